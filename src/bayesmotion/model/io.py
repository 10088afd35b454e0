"""Loading model files (:mod:`bayesmotion.model.archive` holds the format and the writer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesmotion.codecs.affective import codec_from_saved
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.model.archive import read_archive
from bayesmotion.model.data import ModelData
from bayesmotion.model.fitted import FittedHGPDM, TrialRecord
from bayesmotion.model.params import STYLE_PREFIX
from bayesmotion.model.spec import HGPDM


def load(path):
    """Load a model file written by ``FittedHGPDM.save``.

    Raises:
        ModelFileError: the file is missing, corrupted, foreign, or of another format version.
    """
    path = Path(path)
    meta, arrays = read_archive(path)
    try:
        spec = HGPDM.from_dict(meta["spec"])
        params = {k: arrays[f"param/{k}"] for k in meta["params"]}
        codecs = tuple(codec_from_saved(m, arrays, f"codec{a}/")
                       for a, m in enumerate(meta["codecs"]))
        if any(c.pose_space != spec.pose_space for c in codecs):
            raise ModelFileError(f"{path}: corrupted model file: its specification's pose space "
                                 f"{spec.pose_space!r} does not match its codecs' "
                                 f"{[c.pose_space for c in codecs]}")
        A = len(codecs)
        data = ModelData(tuple(arrays[f"Y/{a}"] for a in range(A)),
                         {f: arrays[f"onehot/{f}"] for f in meta["factors"]},
                         np.repeat(np.arange(len(arrays["lengths"])), arrays["lengths"]),
                         arrays["lengths"])
        trials = tuple(
            TrialRecord(t["name"], t["labels"], int(t["n_frames"]),
                        tuple(arrays[f"anchor/{r}/{a}"] for a in range(A)),
                        tuple(arrays[f"offsets/{r}/{a}"] for a in range(A)))
            for r, t in enumerate(meta["trials"]))
        model = FittedHGPDM(spec=spec, params=params, codecs=codecs,
                            levels={k: tuple(v) for k, v in meta["levels"].items()}, data=data,
                            trials=trials, fps=float(meta["fps"]),
                            diagnostics=meta.get("diagnostics", {}))
    except ModelFileError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, BayesmotionError) as e:
        raise ModelFileError(f"{path}: corrupted or incomplete model file ({type(e).__name__}: "
                             f"{e})") from None
    _check_shapes(model, path)
    return model


def _check_shapes(model, path):
    """Every array the model uses has the shape its metadata implies, and finite values: a
    file that passes cannot fail later inside ``log_posterior`` or ``generate``."""
    def bad(msg):
        raise ModelFileError(f"{path}: corrupted model file: {msg}")

    spec, data, params = model.spec, model.data, model.params
    lengths = np.asarray(data.lengths)
    if lengths.ndim != 1 or lengths.size != len(model.trials) or np.any(lengths < 1):
        bad(f"trial lengths {lengths.tolist()} do not match the {len(model.trials)} trials")
    if any(int(n) != r.n_frames for n, r in zip(lengths, model.trials, strict=True)):
        bad("trial lengths disagree with the trial records")
    N, R, A = int(lengths.sum()), lengths.size, len(model.codecs)
    o = spec.order
    expected = {"X": (A, N, spec.latent_dim), "I": (N, spec.interaction_dim),
                "log_gamma": (3,), "log_beta": (3,), "log_alpha": (2 + 2 * o,)}
    if set(data.onehot) != set(spec.factors) or not set(spec.factors) <= set(model.levels):
        bad(f"labels of factors {sorted(data.onehot)} (levels of {sorted(model.levels)}) do not "
            f"match the specification's factors {sorted(spec.factors)}")
    for f in spec.factors:
        K = len(model.levels[f])
        h = np.asarray(data.onehot[f])
        if h.shape != (R, K) or not np.all((h == 0) | (h == 1)) or np.any(h.sum(1) != 1):
            bad(f"labels of factor {f!r} are not one-hot ({R}, {K}) over its levels")
        if STYLE_PREFIX + f in params:
            expected[STYLE_PREFIX + f] = (K, K - 1)
    missing = sorted(k for k in expected if k not in params)  # style keys: only if present
    unknown = sorted(set(params) - set(expected))
    if missing or unknown:
        bad(f"parameters missing {missing}, unknown {unknown}")
    for k, shape in expected.items():
        v = np.asarray(params[k])
        if v.shape != shape:
            bad(f"parameter {k} has shape {v.shape}, expected {shape}")
        if not np.issubdtype(v.dtype, np.floating) or not np.all(np.isfinite(v)):
            bad(f"parameter {k} is not a finite float array")
    for a, Y in enumerate(data.Y):
        if Y.shape != (N, model.codecs[a].dim):
            bad(f"training poses of actor {a} have shape {Y.shape}, expected "
                f"{(N, model.codecs[a].dim)}")
        if not np.all(np.isfinite(Y)):
            bad(f"training poses of actor {a} are not finite")
