"""Argument validation shared by the command line and the public API.

Numbers are checked for type, range and finiteness up front; style values (a level name or
coordinates) for finite, bounded coordinates; output paths for being writable before any work
starts. Resource guards estimate the memory of the package's heavy steps (fit, posterior
sampling, generation, emotion inference) and refuse a request whose estimate exceeds the memory
the machine has available, naming both numbers; turn them off with :func:`memory_checks` (the
CLI: ``--no-memory-check``).

The estimates are deliberately coarse upper bounds of the dominant arrays (their formulas are in
each function's docstring): they exist to refuse requests that are off by orders of magnitude
(a 10^8-sample rollout, a 10^7-step chain) in milliseconds, instead of minutes of swapping or an
abort inside XLA.

Every check raises :class:`~bayesmotion.errors.BayesmotionError` saying what was wrong and what
to do. This module imports only the standard library, NumPy and :mod:`bayesmotion.errors`.
"""

from __future__ import annotations

import contextlib
import contextvars
import numbers
import os
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from bayesmotion.errors import BayesmotionError

MAX_COORDINATE = 1e6
"""Largest absolute style coordinate accepted (the simplex is [0, 1]; extrapolation to a few
units is meaningful, 1e150 only overflows the kernels to NaN)."""
MAX_FPS = 1000.0
"""Largest frame rate a dataset may be resampled to (fast motion capture records at 120-480)."""
SEED_BOUND = 2**32
"""Seeds are integers in ``[0, SEED_BOUND)``: the range NumPy's ``RandomState`` accepts."""

BYTES = 8  # float64
GRADIENT_FACTOR = 8
"""N x N arrays held per layer by a value-and-gradient of the log-posterior: the Gram matrix,
its Cholesky factor, the inverse (or its solves), their cotangents and XLA temporaries."""
EVAL_FACTOR = 3
"""N x N arrays held per layer by one log-posterior evaluation: Gram matrix, factor, temporary."""
LBFGS_COPIES = 24
"""Copies of the parameter vector held by L-BFGS (10 pairs of history, gradients, line search)."""
CHAIN_COPIES = 3
"""Copies of a stored chain held at once (the backend's array, ``get_chain``'s, the posterior's)."""
FRAME_FLOATS_PER_JOINT = 12
"""Floats per generated frame and joint: positions, their variance, channel values and theirs
(3 each), counted again for the pose space and forward kinematics temporaries."""

_MEMORY_CHECKS = contextvars.ContextVar("bayesmotion_memory_checks", default=True)
_OVERRIDE = ("turn this check off with --no-memory-check (command line) or "
             "'with bayesmotion.validate.memory_checks(False):' (Python)")


# --------------------------------------------------------------------------- numbers
def _is_bool(value) -> bool:
    return isinstance(value, bool | np.bool_)


def integer(value, name: str, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int: a Python or NumPy integer (not a bool, not a float such as 2.5)
    in ``[low, high]``."""
    if _is_bool(value) or not isinstance(value, numbers.Integral):
        raise BayesmotionError(f"{name} must be an integer{_range(low, high)}, got {value!r}")
    value = int(value)
    if (low is not None and value < low) or (high is not None and value > high):
        raise BayesmotionError(f"{name} must be an integer{_range(low, high)}, got {value}")
    return value


def _range(low, high) -> str:
    if low is not None and high is not None:
        return f" in [{low}, {high}]"
    if low is not None:
        return f" >= {low}"
    return "" if high is None else f" <= {high}"


def real(value, name: str, above: float | None = None, at_most: float | None = None) -> float:
    """``value`` as a finite float, ``> above`` and ``<= at_most`` where given (bools and
    strings refused)."""
    want = (f"a finite number{'' if above is None else f' > {above:g}'}"
            f"{'' if at_most is None else f' and <= {at_most:g}'}")
    if _is_bool(value) or not isinstance(value, numbers.Real):
        raise BayesmotionError(f"{name} must be {want}, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or (above is not None and value <= above) or (
            at_most is not None and value > at_most):
        raise BayesmotionError(f"{name} must be {want}, got {value:g}")
    return value


def seed(value, name: str = "seed") -> int:
    """A seed: an integer in ``[0, 2**32)``."""
    if _is_bool(value) or not isinstance(value, numbers.Integral) or not (
            0 <= int(value) < SEED_BOUND):
        raise BayesmotionError(f"{name} must be an integer in [0, 2**32), got {value!r}")
    return int(value)


def coordinates(value, name: str, bound: float = MAX_COORDINATE) -> np.ndarray:
    """Style coordinates as a float64 array: numbers only (not labels), finite, each of
    absolute value at most ``bound``."""
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError) as e:  # ragged nesting
        raise BayesmotionError(f"{name} must be a level name or a list of numbers, got "
                               f"{_short(value)} ({e})") from None
    if arr.dtype.kind in "USO" or arr.dtype.kind not in "iuf":
        raise BayesmotionError(f"{name} must be one level name (e.g. 'happy') or coordinates "
                               f"(numbers, e.g. [0.5, 0.5]), got {_short(value)}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise BayesmotionError(f"{name} coordinates must be finite, got {_short(value)}")
    if arr.size and np.max(np.abs(arr)) > bound:
        raise BayesmotionError(f"{name} coordinates must lie within +-{bound:g} (the simplex is "
                               f"[0, 1]; a few units already extrapolate far), got "
                               f"{_short(value)}")
    return arr


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def style_value(value, name: str) -> None:
    """A style given to generation or inference: a level name, coordinates (checked with
    :func:`coordinates`), a per-frame (T, K) array, or a transition (a named tuple with
    ``source``, ``target``, ``start``, ``length``); ``None`` means the default."""
    if value is None or isinstance(value, str):
        return
    fields = getattr(value, "_fields", None)
    if fields is not None and {"source", "target", "start", "length"} <= set(fields):
        style_value(value.source, f"{name} transition source")
        style_value(value.target, f"{name} transition target")
        integer(value.start, f"{name} transition start")
        integer(value.length, f"{name} transition length", low=0)
        return
    coordinates(value, name)


# --------------------------------------------------------------------------- memory
@contextlib.contextmanager
def memory_checks(enabled: bool = True) -> Iterator[None]:
    """Turn the memory guards on or off inside a ``with`` block (on by default)::

        with bayesmotion.validate.memory_checks(False):
            model.generate(n_frames=100_000)
    """
    token = _MEMORY_CHECKS.set(bool(enabled))
    try:
        yield
    finally:
        _MEMORY_CHECKS.reset(token)


def available_memory(meminfo: str = "/proc/meminfo",
                     cgroup: str = "/sys/fs/cgroup") -> int | None:
    """Bytes of memory available to a new allocation: ``MemAvailable`` of ``meminfo`` (Linux),
    else free physical pages times the page size (``os.sysconf``), lowered to the room left
    under the cgroup v2 limit of ``cgroup`` (``memory.max - memory.current``) where one is set;
    ``None`` when the machine does not say."""
    found = None
    try:
        with open(meminfo, encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        found = None
    if found is None:
        try:
            found = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            found = None
    room = _cgroup_room(cgroup)
    if room is not None:
        found = room if found is None else min(found, room)
    return found


def _cgroup_room(root: str) -> int | None:
    try:
        limit = Path(root, "memory.max").read_text().strip()
        used = Path(root, "memory.current").read_text().strip()
        if limit == "max":
            return None
        return max(int(limit) - int(used), 0)
    except (OSError, ValueError):
        return None


def fit_memory(n_frames: int, n_layers: int, latent_dims: int = 0,
               inducing: int | None = None) -> int:
    """Bytes of a MAP fit, about ``8 * (GRADIENT_FACTOR * n_layers * N * C + LBFGS_COPIES * N *
    latent_dims)`` for N training frames: every layer's N x C kernel arrays under a
    value-and-gradient (C = N for the exact model, min(N, M) for a sparse one with M inducing
    points), plus L-BFGS's copies of the latent coordinates (``latent_dims`` per frame, summed
    over actors and the interaction layer)."""
    N = int(n_frames)
    C = N if inducing is None else min(N, int(inducing))
    return BYTES * (GRADIENT_FACTOR * int(n_layers) * N * C + LBFGS_COPIES * N * int(latent_dims))


def sample_memory(n_walkers: int, n_steps: int, ndim: int, n_frames: int, n_layers: int,
                  inducing: int | None = None) -> int:
    """Bytes of a posterior sampling run: the chain, ``8 * CHAIN_COPIES * W * S * ndim`` for W
    walkers and S steps, plus the conditional MAP's fit (:func:`fit_memory`), plus one
    half-ensemble of log-posterior evaluations, ``8 * EVAL_FACTOR * (W // 2) * n_layers * N * C``
    (C as in :func:`fit_memory`)."""
    W, N = int(n_walkers), int(n_frames)
    C = N if inducing is None else min(N, int(inducing))
    chain = BYTES * CHAIN_COPIES * W * int(n_steps) * int(ndim)
    batch = BYTES * EVAL_FACTOR * max(W // 2, 1) * int(n_layers) * N * C
    return chain + fit_memory(N, n_layers, inducing=inducing) + batch


def generate_memory(n_frames: int, n_samples: int, n_joints: int, n_train_frames: int,
                    n_layers: int, sample_memory: int = 0) -> int:
    """Bytes of a generated rollout of T frames with S sampled rollouts besides the mean:
    ``8 * (S + 1) * T * (FRAME_FLOATS_PER_JOINT * 3 * J + n_layers * N)`` for J joints (all
    actors) and N training frames: every frame's positions, channel values and their
    variances, and its cross-covariances with the training inputs of every layer; plus, for
    samples conditioned on the last W = ``sample_memory`` steps of their path,
    ``8 * S * w * (N + 3 w)`` with w = min(W, T): each sample's buffer of whitened
    cross-covariances and its (w x w) covariance, system and factor."""
    per_frame = FRAME_FLOATS_PER_JOINT * 3 * int(n_joints) + int(n_layers) * int(n_train_frames)
    w = min(int(sample_memory), int(n_frames))
    buffers = int(n_samples) * w * (int(n_train_frames) + 3 * w)
    return BYTES * ((int(n_samples) + 1) * int(n_frames) * per_frame + buffers)


def infer_memory(clip_frames: int, n_train_frames: int, n_layers: int, n_walkers: int,
                 n_steps: int, n_coords: int = 8) -> int:
    """Bytes of an emotion inference for a clip of T frames (at the model's rate):
    ``8 * GRADIENT_FACTOR * n_layers * T * N`` for the projection's cross-covariances with the
    N training frames under a value-and-gradient, plus the style chain
    ``8 * CHAIN_COPIES * n_walkers * n_steps * n_coords``."""
    T, N = int(clip_frames), int(n_train_frames)
    return BYTES * (GRADIENT_FACTOR * int(n_layers) * T * N
                    + CHAIN_COPIES * int(n_walkers) * int(n_steps) * int(n_coords))


def check_memory(need: int, what: str, available: int | None = None) -> None:
    """Refuse ``what`` when its estimate ``need`` (bytes) exceeds the available memory
    (:func:`available_memory` unless given); nothing happens inside ``memory_checks(False)`` or
    when the machine does not say how much memory it has."""
    if not _MEMORY_CHECKS.get():
        return
    have = available_memory() if available is None else available
    if have is not None and need > have:
        raise BayesmotionError(f"{what} needs about {_size(need)} of memory (estimated), more "
                               f"than the {_size(have)} available; ask for less, or {_OVERRIDE}")


def _size(n: int) -> str:
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 2**10:.3g} KiB"


# --------------------------------------------------------------------------- paths
def output_file(path, name: str = "--out") -> Path:
    """A file path that can be written: not a folder, and its nearest existing parent a
    writable folder (missing parents are created by the writer). Nothing is created here."""
    path = Path(path)
    if str(path) == "" or path.is_dir():
        raise BayesmotionError(f"{name} {path}: is a folder; give the path of the file to write "
                               f"(e.g. {path / 'model.npz'})")
    if path.exists() and not os.access(path, os.W_OK):
        raise BayesmotionError(f"{name} {path}: the file exists and cannot be overwritten "
                               f"(permission denied); choose another path")
    _writable_parent(path.parent, path, name)
    return path


def output_dir(path, name: str = "--out") -> Path:
    """A folder that exists and is writable, or can be created under a writable folder."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise BayesmotionError(f"{name} {path}: is a file, expected a folder to write into; "
                               f"choose another path")
    if path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise BayesmotionError(f"{name} {path}: the folder is not writable (permission "
                                   f"denied); choose another folder")
        return path
    _writable_parent(path.parent, path, name)
    return path


def _writable_parent(parent: Path, path: Path, name: str) -> None:
    """The nearest existing ancestor of ``path`` must be a folder we may create entries in."""
    anc = parent if str(parent) else Path(".")
    while not anc.exists():
        if anc.is_symlink():  # a dangling link: nothing can be created through it
            raise BayesmotionError(f"{name} {path}: {anc} is a broken link; choose another path")
        anc = anc.parent
    if not anc.is_dir():
        raise BayesmotionError(f"{name} {path}: {anc} is a file, not a folder; choose another "
                               f"path")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise BayesmotionError(f"{name} {path}: cannot create it in {anc} (permission denied); "
                               f"choose a writable folder")


def input_file(path, name: str) -> Path:
    """An existing regular file (not a folder, FIFO or device)."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except OSError:
        raise BayesmotionError(f"{name} {path}: no such file") from None
    if not stat.S_ISREG(mode):
        raise BayesmotionError(f"{name} {path}: not a regular file; give a file's path")
    return path


# --------------------------------------------------------------------------- BVH headers
def bvh_header(path, max_bytes: int = 2**24) -> tuple[int, float] | None:
    """``(frames, frame time)`` declared by a BVH file's ``MOTION`` header, read without parsing
    the hierarchy or the frames; ``None`` when the file is not a regular file or no such header
    appears in its first ``max_bytes`` (the BVH reader then reports the problem)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return None
        frames = None
        with open(path, "rb") as f:
            read = 0
            for line in f:
                read += len(line)
                if read > max_bytes:
                    return None
                text = line.strip()
                if text.lower().startswith(b"frames:"):
                    frames = int(text.split(b":", 1)[1])
                elif text.lower().startswith(b"frame time:"):
                    dt = float(text.split(b":", 1)[1])
                    ok = frames is not None and frames >= 0 and np.isfinite(dt) and dt > 0
                    return (frames, dt) if ok else None
    except (OSError, ValueError):
        return None
    return None


def clip_frames(clip, fps: float) -> int | None:
    """Frames of a clip at ``fps`` (the model's rate), as :func:`infer_emotion` will see it:
    BVH path(s) from their headers, a Motion or Trial from its frames and rate, model-space
    poses from their shape; ``None`` when it cannot tell (the reader then checks the clip)."""
    if isinstance(clip, str | os.PathLike):
        head = bvh_header(clip)
        return None if head is None else int(np.ceil(head[0] * head[1] * fps))
    if isinstance(clip, list | tuple):
        counts = [clip_frames(c, fps) for c in clip]
        counts = [c for c in counts if c is not None]
        return max(counts) if counts else None
    actors = getattr(clip, "actors", None)
    if actors is not None:
        return clip_frames(tuple(actors), fps)
    values, rate = getattr(clip, "values", None), getattr(clip, "fps", None)
    if values is not None and rate:
        return int(np.ceil(np.shape(values)[0] * fps / float(rate)))
    shape = getattr(clip, "shape", None)
    if shape is not None and len(shape) >= 2:
        return int(shape[-2])
    return None


# --------------------------------------------------------------------------- public API calls
def check_generate_args(n_frames, n_samples, seed_value, styles: dict) -> None:
    """The numbers and style values given to :func:`bayesmotion.model.generate.generate`."""
    integer(n_frames, "n_frames", low=1)
    integer(n_samples, "n_samples", low=0)
    seed(seed_value)
    for factor, value in styles.items():
        style_value(value, factor)


def check_generate_memory(n_frames: int, n_samples: int, n_joints: int, n_train_frames: int,
                          n_layers: int, sample_memory: int = 0) -> None:
    """Refuse a rollout whose :func:`generate_memory` exceeds the available memory."""
    need = generate_memory(n_frames, n_samples, n_joints, n_train_frames, n_layers,
                           sample_memory)
    check_memory(need, f"generating {n_frames} frames with {n_samples} sampled rollouts")


def check_infer_args(seed_value, n_walkers, n_steps, n_draws, couple, styles, prior) -> None:
    """The numbers and style values given to :func:`bayesmotion.emotion.infer.infer_emotion`."""
    seed(seed_value)
    integer(n_walkers, "n_walkers", low=1)
    integer(n_steps, "n_steps", low=3)
    integer(n_draws, "n_draws", low=1)
    style_value(couple, "couple")
    if styles is not None and not isinstance(styles, Mapping):
        raise BayesmotionError(f"styles must be a dict, factor -> label or coordinates (e.g. "
                               f"{{'couple': 'c1'}}), got {_short(styles)}")
    for factor, value in (styles or {}).items():
        style_value(value, str(factor))
    if prior is not None:
        c = coordinates(prior, "prior")
        if np.any(c <= 0):
            raise BayesmotionError(f"prior must hold positive Dirichlet concentrations, got "
                                   f"{_short(prior)}")


def check_projection_starts(emotion_starts, level_starts, start_jitter,
                            flag: str = "level_starts", jitter_flag: str = "start_jitter"
                            ) -> None:
    """``infer_emotion``'s ``emotion_starts``, ``level_starts`` and ``start_jitter`` (``flag``,
    ``jitter_flag``: how the caller names the latter two, e.g. ``--level-starts``), checked
    before any work is started."""
    if emotion_starts not in ("nearest", "levels", "vertices"):
        raise BayesmotionError(f"emotion_starts must be 'nearest', 'levels' or 'vertices', "
                               f"got {emotion_starts!r}")
    if _is_bool(level_starts) or not isinstance(level_starts, numbers.Integral) \
            or level_starts < 1:
        raise BayesmotionError(f"{flag} (projections per emotion level) must be a positive "
                               f"integer, got {level_starts!r}")
    if level_starts > 1 and emotion_starts != "vertices":
        raise BayesmotionError(f"{flag} > 1 needs emotion_starts='vertices' (one projection "
                               f"per level), got {emotion_starts!r}")
    try:
        sd = float(start_jitter)
    except (TypeError, ValueError, OverflowError):
        sd = float("nan")
    if _is_bool(start_jitter) or not isinstance(start_jitter, numbers.Real) \
            or not np.isfinite(sd) or sd < 0:
        raise BayesmotionError(f"{jitter_flag} (sd of the jitter of the level projections' "
                               f"jittered starts, latent units) must be a finite number >= 0, "
                               f"got "
                               f"{start_jitter!r}")
    if start_jitter > 0 and emotion_starts != "vertices":
        raise BayesmotionError(f"{jitter_flag} > 0 needs emotion_starts='vertices' (it jitters "
                               f"the level projections' starts), got {emotion_starts!r}")
    if level_starts > 1 and start_jitter == 0:
        raise BayesmotionError(f"{flag} > 1 needs {jitter_flag} > 0 (e.g. 0.02): unjittered "
                               f"starts are all the same point")


def check_pad_to(pad_to) -> None:
    """``infer_emotion``'s ``pad_to``: None or a positive number of frames."""
    if pad_to is not None and (isinstance(pad_to, bool)
                               or not isinstance(pad_to, int | np.integer) or pad_to < 1):
        raise BayesmotionError(f"pad_to must be a positive number of frames or None, got "
                               f"{pad_to!r}")


def check_infer_memory(clip, fps: float, n_train_frames: int, n_layers: int, n_walkers: int,
                       n_steps: int, pad_to: int | None = None) -> None:
    """Refuse an inference whose :func:`infer_memory` exceeds the available memory (the clip's
    frames from :func:`clip_frames`, or ``pad_to`` where more; unknown: not checked here)."""
    T = clip_frames(clip, fps)
    what = f"a {T}-frame clip"
    if pad_to is not None and int(pad_to) > (T or 0):
        T, what = int(pad_to), f"a clip padded to {pad_to} frames"
    if T is not None:
        check_memory(infer_memory(T, n_train_frames, n_layers, n_walkers, n_steps),
                     f"inferring the emotion of {what}")
