"""Generation with predictive uncertainty (Taubert et al. eq. 13-16, plus sampling).

One concept: a rollout, from the style arguments and the start state through the jitted
dynamics scan (plain, sampled, path-conditioned or guided by the look-ahead) and the top-down
mapping to decoded poses, with the checks each step needs.

The dynamics layer is rolled out under ``lax.scan`` from a start state: by mean prediction, or,
for ``n_samples > 0``, by drawing every step from the GP predictive ``N(mean, var + 1/alpha_noise)``
(``vmap`` over samples). By default each step is drawn given the previous *values* only, not
the GP's function values at earlier inputs (the usual sequential approximation, as in the
enhanced-GPDM of Ko & Fox); ``sample_memory=W`` conditions each step on the last W steps of its
own path too (:func:`_path_sampled_rollout`). Every latent trajectory is then mapped top-down
by mean prediction through the interaction and bottom layers (batched over frames) and to joint
positions by forward kinematics.

Reported along the rollout:

* ``*_var``: the one-step predictive variance of each layer along the mean rollout (latent I,
  latent X, pose Y), carried to joint angles (times the codec scale squared) and joint positions
  (first-order propagation through forward kinematics);
* ``samples`` and ``sample_var``: the sampled rollouts and their spread in the same spaces.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.data.fk import forward_kinematics, forward_kinematics_with_variance
from bayesmotion.errors import BayesmotionError
from bayesmotion.gp import kernels
from bayesmotion.model import layers
from bayesmotion.model.predict import (
    Predictor,
    dynamics_mean_stepper,
    noise_variances,
    predict_bottom,
    predict_bottom_mean,
    predict_dynamics,
    predict_interaction,
    predict_interaction_mean,
    restrict_to_styles,
    style_vectors,
    whiten,
)
from bayesmotion.model.registration import MAX_SLOPE as REG_MAX_SLOPE
from bayesmotion.model.registration import blend as reg_blend
from bayesmotion.model.registration import registration
from bayesmotion.model.rollout import Rollout
from bayesmotion.validate import check_generate_args, check_generate_memory, integer


class Transition(NamedTuple):
    """A style that changes from ``source`` to ``target``: the target's weight rises from 0 at
    frame ``start`` to 1 at frame ``start + length`` along a smoothstep, as in the emotion
    transitions of Bhattacharya et al. (2021); ``length = 0`` switches at frame ``start``.

    ``source`` / ``target`` are level names or coordinate vectors.

    With ``match=True`` the rollout instead follows ``source`` up to frame ``start`` and then
    continues from the training frame of ``target`` (a level name) whose poses best match its
    last frames, and the pose difference at the switch is blended out over ``length`` frames
    (:mod:`bayesmotion.model.transition`). ``within`` (matched only) lets the switch come at
    any frame from ``start`` to ``start + within``: the one whose last poses a target training
    frame matches best, as motion graphs take their transitions at the minima of the pose
    distance (e.g. ``within`` = one gait cycle, so the switch finds the step phase where the
    two emotions' poses are closest).
    """

    source: object
    target: object
    start: int
    length: int
    match: bool = False
    within: int = 0


def style_coords(model, factor, value) -> np.ndarray:
    K = len(model.levels[factor])
    if isinstance(value, str):
        return np.eye(K)[model.level_index(factor, value)]
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (K,):
        raise BayesmotionError(f"{factor} coordinates must have {K} entries "
                               f"({', '.join(model.levels[factor])}), got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise BayesmotionError(f"{factor} coordinates must be finite")
    return v


def resolve_style(model, factor: str, value, n_frames: int) -> np.ndarray:
    """A style value -> (T, K) per-frame coordinates (label, vector, (T, K) array, Transition)."""
    if factor not in model.levels:
        raise BayesmotionError(f"model has no style factor {factor!r}")
    K = len(model.levels[factor])
    if isinstance(value, Transition):
        a, b = style_coords(model, factor, value.source), style_coords(model, factor, value.target)
        if value.length < 0:
            raise BayesmotionError(f"a Transition's length must be >= 0, got {value.length}")
        if value.within and not value.match:
            raise BayesmotionError(f"a Transition's within={value.within!r} searches for the "
                                   f"best-matched switch frame: it needs match=True")
        f = np.arange(n_frames) - value.start
        t = (np.clip(f / value.length, 0.0, 1.0) if value.length > 0 and not value.match
             else (f >= 0).astype(np.float64))
        w = t * t * (3 - 2 * t)
        return (1 - w)[:, None] * a + w[:, None] * b
    arr = np.asarray(value) if not isinstance(value, str) else None
    if arr is not None and arr.ndim == 2:
        if arr.shape != (n_frames, K):
            raise BayesmotionError(f"time-varying {factor} must be ({n_frames}, {K}), "
                                   f"got {arr.shape}")
        return np.asarray(arr, dtype=np.float64)
    return np.tile(style_coords(model, factor, value), (n_frames, 1))


def is_extrapolated(coords: np.ndarray) -> bool:
    """True when any frame's coordinates leave the simplex (negative or not summing to 1)."""
    return bool(np.any(coords < -1e-9) or np.any(np.abs(coords.sum(-1) - 1) > 1e-6))


# --------------------------------------------------------------------------- the jitted core
LOOKAHEAD_ITERATIONS = 4  # descent iterations of a look-ahead step
LOOKAHEAD_STEPS = (1.0, 0.5, 0.25, 0.125)  # the step lengths each iteration tries
LOOKAHEAD_MAX_SD = 3.0  # a look-ahead step moves the mean by at most this many predictive sd


def lookahead_step(P: Predictor, lags, s_now, s_next, weight, noise):
    """One look-ahead step: (the new latent (Q,), the one-step variance with noise).

    The step's value z minimises the negative log predictive density of the step,
    |z - mu|^2 / (2 v), plus ``weight`` times the next step's log predictive variance,
    (Q / 2) log v_next(z), v_next from the lags (z, lags[:-1]) at the next step's styles
    ``s_next``. weight = 1 is the MAP of this step given that the next one is drawn at its
    own mean (a two-step look-ahead); a larger weight stands in for more future steps
    depending on this one. Far from the training latents v_next grows, so the step is pulled
    back to where the dynamics has data.

    Minimised from z = mu by ``LOOKAHEAD_ITERATIONS`` steps of gradient descent
    preconditioned by v, each trying the lengths ``LOOKAHEAD_STEPS`` at once and keeping the
    lowest objective if it is lower than the current one; z stays within
    ``LOOKAHEAD_MAX_SD`` predictive standard deviations sqrt(v) of mu (a trust region: the step
    remains a plausible draw of the predictive). The objective never rises.
    """
    Q = lags.shape[-1]

    def mean_var(lg, s):
        m, v = predict_dynamics(P, lg[:, None, :], [x[None] for x in s])
        return m[0], v[0] + noise

    mu, v = mean_var(lags, s_now)

    def objective(z):
        nxt = mean_var(jnp.concatenate([z[None], lags[:-1]]), s_next)[1]
        return jnp.sum((z - mu) ** 2) / (2.0 * v) + weight * 0.5 * Q * jnp.log(nxt)

    def inside(z):  # (n, Q) points moved into the trust region around mu
        d = z - mu
        r = jnp.sqrt(jnp.sum(d * d, -1, keepdims=True) / v)
        return mu + d * jnp.minimum(1.0, LOOKAHEAD_MAX_SD / jnp.maximum(r, 1e-300))

    value_and_grad = jax.value_and_grad(objective)
    steps = jnp.asarray(LOOKAHEAD_STEPS)
    z = mu
    for _ in range(LOOKAHEAD_ITERATIONS):
        f, g = value_and_grad(z)
        cand = inside(z[None] - steps[:, None] * v * g[None])
        fc = jax.vmap(objective)(cand)
        fc = jnp.where(jnp.isfinite(fc), fc, jnp.inf)
        best = jnp.argmin(fc)
        z = jnp.where(fc[best] < f, cand[best], z)
    return z, v


@partial(jax.jit, static_argnames=("n_steps", "sample", "with_var", "memory", "guided"))
def dynamics_rollout(P: Predictor, I0, styles, key, n_steps: int, sample: bool,
                     with_var: bool = True, memory: int = 0, guided: bool = False,
                     lookahead=0.0):
    """Roll the dynamics forward n_steps from I0 (o, Q) with per-step styles (n_steps, K_f).

    Returns (I (n_steps, Q), one-step variance (n_steps,) including the dynamics noise; None
    for a mean rollout with ``with_var=False``).

    The mean rollout needs only the predictive means, O(M Q) per step inside ``lax.scan``;
    its one-step variances are computed afterwards for all steps at once (one product of L^-1
    with the n_steps cross-covariance columns). A sampled rollout needs each step's variance to
    draw it, so it computes it inside the scan.

    ``guided`` (with ``lookahead`` > 0, not with ``memory``): each step's mean is the
    :func:`lookahead_step` of weight ``lookahead`` instead of the predictive mean; a sampled
    step draws around it with the predictive variance.
    """
    noise = noise_variances(P)["I"]
    o = I0.shape[0]
    if guided:
        st = tuple(styles)
        nxt = tuple(jnp.concatenate([s[1:], s[-1:]]) for s in st)

        def guided_step(lags, inp):
            s_now, s_next, k = inp
            z, v = lookahead_step(P, lags, s_now, s_next, lookahead, noise)
            if sample:
                z = z + jnp.sqrt(v) * jax.random.normal(k, z.shape)
            return jnp.concatenate([z[None], lags[:-1]], axis=0), (z, v)

        _, (I, v) = jax.lax.scan(guided_step, I0[::-1],
                                 (st, nxt, jax.random.split(key, n_steps)))
        return I, v

    predict_mean, style_rows = dynamics_mean_stepper(P, styles)
    if not styles:  # no dynamics factors: every training row's style factor is 1
        style_rows = jnp.ones((n_steps, P.dyn.A.shape[0]))

    def mean_step(lags, style_row):
        new = predict_mean(lags, style_row)
        return jnp.concatenate([new[None], lags[:-1]], axis=0), new

    def sample_step(lags, inp):
        s, k = inp
        mean, var = predict_dynamics(P, lags[:, None, :], [x[None] for x in s])
        v = var[0] + noise
        new = mean[0] + jnp.sqrt(v) * jax.random.normal(k, mean[0].shape)
        return jnp.concatenate([new[None], lags[:-1]], axis=0), (new, v)

    if sample:
        keys = jax.random.split(key, n_steps)
        if memory > 0:
            return _path_sampled_rollout(P, I0, styles, keys, min(memory, n_steps))
        _, (I, v) = jax.lax.scan(sample_step, I0[::-1], (tuple(styles), keys))
        return I, v
    _, I = jax.lax.scan(mean_step, I0[::-1], style_rows)
    if not with_var:
        return I, None
    full = jnp.concatenate([I0, I])
    lags = jnp.stack([full[o - 1 - k:o - 1 - k + n_steps] for k in range(o)])
    _, var = predict_dynamics(P, lags, list(styles))
    return I, var + noise


def _path_sampled_rollout(P: Predictor, I0, styles, keys, memory: int):
    """A sampled rollout whose every step is drawn given the training data *and* the last
    ``memory`` steps of its own path (inputs and drawn values), as if they were training data of
    the dynamics GP: within those steps the sampled function is one function, and a rollout of
    at most ``memory`` steps is a draw of the GP's joint distribution along its path (given the
    fitted parameters); older steps are forgotten (a sliding window).

    Drawn independently, each step's deviation from the mean is white noise; once a path leaves
    the training latents its predictive variance approaches the kernel's signal variance and the
    white noise becomes the motion's jerk. Conditioned on its own path, the deviation at an
    input near earlier inputs follows theirs (benchmarks/results/sample_paths.json measures what
    that does to jerk, range and limb motion).

    The path's pseudo-observations enter through their covariance given the training data,
    c(u, u') = k(u, u') - (L^-1 k_u)^T (L^-1 k_u'), kept for a ring buffer of ``memory`` steps
    with each step's whitened cross-covariance; a step costs one (memory x memory) Cholesky
    factor on top of the independent draw's O(M^2). Returns (I (n_steps, Q), the conditional
    one-step variance (n_steps,) including the dynamics noise)."""
    noise = noise_variances(P)["I"]
    o, Q = I0.shape
    W = memory
    Mw = whiten(P.dyn, jnp.zeros((P.dyn.A.shape[0], 1), I0.dtype)).shape[0]
    nugget = noise + 1e-10 * P.alpha[0]
    carry0 = (I0[::-1], jnp.zeros((o, W, Q), I0.dtype),
              tuple(jnp.zeros((W, s.shape[-1]), I0.dtype) for s in styles),
              jnp.zeros((W, Mw), I0.dtype), jnp.zeros((W, Q), I0.dtype),
              jnp.zeros((W, W), I0.dtype), jnp.zeros(W, I0.dtype), jnp.asarray(0))

    def step(carry, inp):
        lags, B_lags, B_sty, B_w, B_r, C, mask, head = carry
        s, k = inp
        x = lags[:, None, :]  # (o, 1, Q)
        sx = [v[None] for v in s]
        kx = kernels.dynamics_kernel(list(P.dyn_lags), list(x), list(P.dyn_style), sx, P.alpha)
        w = whiten(P.dyn, kx)[:, 0]
        m = (kx.T @ P.dyn.A)[0] + layers.ar_mean(x, P.ar)[0]
        v0 = jnp.maximum(kernels.dynamics_diag(list(x), sx, P.alpha)[0] - w @ w, 0.0)
        kb = kernels.dynamics_kernel(list(B_lags), list(x), list(B_sty), sx, P.alpha)[:, 0]
        c = kb - B_w @ w  # covariance with each buffered step given the training data
        cm = c * mask
        G = C * mask[:, None] * mask[None] + jnp.diag(mask * nugget + (1.0 - mask))
        L = jnp.linalg.cholesky(G)
        a = jax.scipy.linalg.cho_solve((L, True), cm)
        mean = m + a @ B_r
        var = jnp.maximum(v0 - cm @ a, 0.0) + noise
        new = mean + jnp.sqrt(var) * jax.random.normal(k, mean.shape)
        row = c.at[head].set(v0)
        C = C.at[head].set(row).at[:, head].set(row)
        B_lags = B_lags.at[:, head].set(lags)
        B_sty = tuple(b.at[head].set(v) for b, v in zip(B_sty, s, strict=True))
        carry = (jnp.concatenate([new[None], lags[:-1]], axis=0), B_lags, B_sty,
                 B_w.at[head].set(w), B_r.at[head].set(new - m), C, mask.at[head].set(1.0),
                 (head + 1) % W)
        return carry, (new, var)

    _, (I, v) = jax.lax.scan(step, carry0, (tuple(styles), keys))
    return I, v


@partial(jax.jit, static_argnames=("n_actors",))
def map_down(P: Predictor, I, int_styles, n_actors: int):
    """Mean prediction top-down for a whole latent trajectory I (T, Q_I)."""
    noise = noise_variances(P)
    Xm, Xv = predict_interaction(P, I, list(int_styles))
    q = Xm.shape[1] // n_actors
    out = []
    for a in range(n_actors):
        Xa = Xm[:, a * q:(a + 1) * q]
        Ym, Yv = predict_bottom(P, a, Xa)
        out.append((Xa, Ym, Yv + noise["Y"]))
    return out, Xv + noise["X"]


@partial(jax.jit, static_argnames=("n_actors",))
def map_down_mean(P: Predictor, I, int_styles, n_actors: int):
    """:func:`map_down`'s means alone, [(X_a, Y_a)] per actor: what sampled rollouts need (their
    spread is measured across samples), without the O(N^2) per-frame variances."""
    Xm = predict_interaction_mean(P, I, list(int_styles))
    q = Xm.shape[1] // n_actors
    actors = [Xm[:, a * q:(a + 1) * q] for a in range(n_actors)]
    return [(Xa, predict_bottom_mean(P, a, Xa)) for a, Xa in enumerate(actors)]


# --------------------------------------------------------------------------- decoding to motion
def _anchor(model, codec, trial: int, actor: int, n_frames: int):
    anchor = np.asarray(model.trials[trial].anchors[actor])
    if codec.root_mode == "partner":
        return np.broadcast_to(anchor.mean(0), (n_frames, anchor.shape[1]))
    return anchor


def decode_actor(model, actor: int, Y, Y_var, trial: int):
    """Y (T, D) and isotropic variance (T,) -> channels (T, C), variance (T, C), skeleton, and
    the same three in the codec's rig (rest frames), where the pose variance is isotropic (the
    positions' variance is computed there: the joint positions are the same on both rigs)."""
    codec = model.codecs[actor]
    sk = model.skeleton(actor, trial)
    T = Y.shape[0]
    motion = codec.decode_rig(np.asarray(Y), _anchor(model, codec, trial, actor, T), sk,
                              model.fps)
    # model-space columns ("heading" appends a heading-rate column after the C channels)
    full = np.zeros((T, codec.constant.size))
    full[:, codec.keep] = np.asarray(Y_var)[:, None] * codec.scale**2
    var = full[:, :motion.values.shape[1]]
    if codec.root_mode in ("velocity", "heading"):
        # positions integrate velocities: variances add up. Approximations: the two velocity
        # columns share one variance (exact with scaling="type", where they share one scale, so
        # rotating body-frame velocity to the world leaves it unchanged); in "heading" mode the
        # heading's own uncertainty (integrated turn-rate variance) is not propagated into the
        # path or the mover's rotation, whose variance is that of its heading-free angles
        h = codec.horizontal_columns(sk)
        var[:, h] = np.concatenate([np.zeros((1, h.size)),
                                    np.cumsum(var[1:, h], 0) / model.fps**2])
    rig = (motion.values, var, motion.skeleton)
    if codec.frames is None:
        return motion.values, var, sk, rig
    return codec.from_rig(motion, sk).values, codec.channel_variance(motion, var), sk, rig


def _positions(sk, values) -> np.ndarray:
    """Joint positions (..., T, J, 3) of channel values (..., T, C)."""
    return np.asarray(forward_kinematics(sk, values))


def _positions_with_var(sk, values, var):
    """Joint positions and their first-order variance (analytic FK Jacobian, see
    :func:`bayesmotion.data.fk.forward_kinematics_with_variance`)."""
    p, v = forward_kinematics_with_variance(sk, values, var)
    return np.asarray(p), np.asarray(v)


# --------------------------------------------------------------------------- the public driver
def start_trial(model, styles, start) -> int:
    """The training trial a rollout starts from (and decodes on): ``start`` when it is a trial
    index, else the longest trial whose labels are the first frame's style vertices."""
    if isinstance(start, int | np.integer):
        if not 0 <= start < len(model.trials):
            raise BayesmotionError(f"start trial {start} out of range (0-{len(model.trials) - 1})")
        return int(start)
    target = {f: np.argmax(c[0]) for f, c in styles.items()}
    match = [r for r, rec in enumerate(model.trials)
             if all(model.levels[f].index(rec.labels[f]) == k for f, k in target.items())]
    # the longest: a short clip (a 1-s recording) ends its trajectory early, and the rollout
    # then continues from where no training trajectory goes on
    return max(match, key=lambda r: model.trials[r].n_frames) if match else 0


DIVERGED = 100.0
"""A rollout whose latents leave the training latents' range by this factor has diverged."""
SAMPLE_MEMORY = 0
"""Steps of its own path each step of a sampled rollout is conditioned on (0: independent
draws given the training data alone); see :func:`_path_sampled_rollout`."""
MAX_SAMPLE_MEMORY = 256
"""The largest ``sample_memory``: each sampled step factors a (W x W) matrix, O(W^3)."""


def check_sample_memory(sample_memory, n_samples) -> int:
    """``sample_memory`` as an int in [0, MAX_SAMPLE_MEMORY], refused with rollouts that draw no
    samples (it would change nothing)."""
    w = integer(sample_memory, "sample_memory", low=0, high=MAX_SAMPLE_MEMORY)
    if w and not n_samples:
        raise BayesmotionError(f"sample_memory={w} conditions sampled rollouts on their path, "
                               f"but n_samples is 0: ask for samples (n_samples > 0) or leave "
                               f"sample_memory at 0")
    return w


def check_lookahead(lookahead, sample_memory: int) -> float:
    """The look-ahead weight as a float: a finite number >= 0, and 0 with ``sample_memory``."""
    if isinstance(lookahead, bool) or not isinstance(lookahead, int | float | np.floating
                                                     | np.integer) \
            or not np.isfinite(lookahead) or lookahead < 0:
        raise BayesmotionError(f"lookahead must be a finite number >= 0 (0: plain predictive "
                               f"means), got {lookahead!r}")
    if lookahead > 0 and sample_memory:
        raise BayesmotionError("lookahead guides step-by-step rollouts; it does not combine "
                               "with sample_memory > 0")
    return float(lookahead)


DYNAMICS_STYLES = ("requested", "nearest", "registered")
"""Where a rollout's dynamics runs (``generate(dynamics_style=...)``): at the requested style
coordinates, at the trained level nearest them (:func:`dynamics_coords`), or at each level
with weight, the levels' paths registered in time and blended (:func:`_registered`)."""


def dynamics_coords(coords: np.ndarray, dynamics_style: str) -> np.ndarray:
    """The style coordinates (T, K) the dynamics runs at: ``coords`` themselves
    (``"requested"``), or per frame the vertex of their largest entry, the first of equal ones
    (``"nearest"``): the trained level the coordinates are nearest to on the simplex. The
    interaction mapping always decodes at ``coords``."""
    if dynamics_style == "requested":
        return coords
    return np.eye(coords.shape[1])[np.argmax(coords, axis=1)]


def check_dynamics_style(dynamics_style) -> str:
    """``dynamics_style`` if it is one of ``DYNAMICS_STYLES``; else a BayesmotionError naming
    them."""
    if not isinstance(dynamics_style, str) or dynamics_style not in DYNAMICS_STYLES:
        raise BayesmotionError(f"dynamics_style must be one of {list(DYNAMICS_STYLES)}, got "
                               f"{dynamics_style!r}")
    return dynamics_style


def check_bounded(I: np.ndarray, I_train: np.ndarray, dynamics_linear: str) -> None:
    """Raise BayesmotionError when a latent rollout is not finite or has left the range of
    ``I_train`` (the training latents and the start) by more than ``DIVERGED`` times, instead
    of decoding it.

    With the default stable dynamics a mean rollout is bounded by construction (a stationary
    autoregression driven by the bounded RBF mean); with the paper's linear kernel term
    (``dynamics_linear="kernel"``) nothing bounds it, and rollouts of real walks reach 1e15
    times the training range within 200 frames."""
    scale = float(np.max(np.abs(I_train))) or 1.0
    peak = float(np.max(np.abs(I))) if np.all(np.isfinite(I)) else np.inf
    if peak > DIVERGED * scale:
        hint = (" (its dynamics has the paper's linear kernel term, which nothing keeps "
                "stable; refit with HGPDM(dynamics_linear='stable'))"
                if dynamics_linear == "kernel" else "")
        raise BayesmotionError(f"the latent rollout diverged: |I| reached {peak:.3g}, "
                               f"{peak / scale:.3g} times the training latents' range{hint}")


def check_decodes(model) -> None:
    """Raise BayesmotionError, naming why, when the model's pose space cannot be decoded to
    motion (``HGPDM(pose_space="affective")``)."""
    for codec in model.codecs:
        if not codec.decodes:
            codec.decode()  # raises with the reason


class LatentPaths(NamedTuple):
    """A rollout's latent paths: the predictor restricted to its styles ``P``, the interaction
    style vectors ``int_s``, the mean path ``I`` (T, Q_I) with its one-step variance ``I_var``
    (T,) (0 at the start frames) and the sampled paths ``I_s`` (S, T, Q_I) or None."""

    P: Predictor
    int_s: tuple
    I: np.ndarray
    I_var: np.ndarray
    I_s: np.ndarray | None


def latent_paths(model, P: Predictor, coords: dict, I0: np.ndarray, n_frames: int,
                 n_samples: int, seed: int, sample_memory: int, lookahead: float,
                 dynamics_style: str) -> LatentPaths:
    """The dynamics rolled out from the start state ``I0`` (order, Q_I) at the per-frame
    style coordinates ``coords`` (factor -> (n_frames, K)): the mean path and ``n_samples``
    sampled ones, each checked to be bounded."""
    o = I0.shape[0]
    dyn_f, int_f = model.spec.dynamics_factors, model.spec.interaction_factors
    dyn_s = tuple(style_vectors(P, dyn_f, [dynamics_coords(coords[f], dynamics_style)[o:]
                                           for f in dyn_f]))
    int_s = tuple(style_vectors(P, int_f, [coords[f] for f in int_f]))
    P = restrict_to_styles(P, dyn_s, int_s)  # exact: drops the style cells no frame sees
    key = jax.random.PRNGKey(seed)
    guide = {"guided": lookahead > 0, "lookahead": lookahead}
    I_gen, I_var = dynamics_rollout(P, jnp.asarray(I0), dyn_s, key, n_frames - o, False,
                                    **guide)
    I = np.concatenate([I0, np.asarray(I_gen)])
    reach = np.concatenate([np.asarray(model.params["I"]), I0])  # a given start counts too
    check_bounded(I, reach, model.spec.dynamics_linear)
    I_s = None
    if n_samples:
        keys = jax.random.split(key, n_samples + 1)[1:]
        roll = jax.vmap(lambda k: dynamics_rollout(P, jnp.asarray(I0), dyn_s, k, n_frames - o,
                                                   True, memory=sample_memory, **guide)[0])
        I_s = np.concatenate([np.broadcast_to(I0, (n_samples, o, I0.shape[1])),
                              np.asarray(roll(keys))], axis=1)
        check_bounded(I_s, reach, model.spec.dynamics_linear)
    return LatentPaths(P, int_s, I, np.concatenate([np.zeros(o), np.asarray(I_var)]), I_s)


def generate(model, emotion="neutral", couple=None, n_frames: int = 100, n_samples: int = 0,
             start=None, seed: int = 0, predictor: Predictor | None = None,
             sample_memory: int = SAMPLE_MEMORY, lookahead: float = 0.0,
             dynamics_style: str = "requested", **styles) -> Rollout:
    """Generate a rollout; see :meth:`FittedHGPDM.generate`."""
    if any(isinstance(v, Transition) and v.match for v in (emotion, couple, *styles.values())):
        raise BayesmotionError("a matched Transition (match=True) is generated by the fitted "
                               "model itself (model.generate), not per posterior draw")
    check_generate_args(n_frames, n_samples, seed, {"emotion": emotion, "couple": couple,
                                                    **styles})
    sample_memory = check_sample_memory(sample_memory, n_samples)
    lookahead = check_lookahead(lookahead, sample_memory)
    dynamics_style = check_dynamics_style(dynamics_style)
    check_generate_memory(n_frames, n_samples,
                          sum(model.skeleton(a).n_joints for a in range(model.n_actors)),
                          model.predictor_rows, model.n_actors + 2, sample_memory)
    check_decodes(model)
    if n_frames <= model.spec.order:
        raise BayesmotionError(f"n_frames must exceed the dynamics order ({model.spec.order})")
    if n_samples < 0:
        raise BayesmotionError("n_samples must be >= 0")
    unknown = sorted(set(styles) - set(model.spec.factors))
    if unknown:
        raise BayesmotionError(f"the model has no style factor {unknown}; its factors are "
                               f"{list(model.spec.factors)}")
    values = dict(styles)
    if "emotion" in model.levels:
        values["emotion"] = emotion
    if "couple" in model.levels:
        values["couple"] = couple if couple is not None else model.levels["couple"][0]
    coords = {f: resolve_style(model, f, values.get(f, model.levels[f][0]), n_frames)
              for f in model.spec.factors}
    _check_trained_levels(model, coords)
    P = model.predictor() if predictor is None else predictor
    o = model.spec.order
    if isinstance(start, str) and start == "prior":
        r, desc = start_trial(model, coords, None), "prior mean"
        I0 = np.zeros((o, model.spec.interaction_dim))
    elif start is None or isinstance(start, int | np.integer):
        r = start_trial(model, coords, start)
        I0 = model.latents(r)["I"][:o]
        desc = f"first {o} frames of training trial {r} ({model.trials[r].name})"
    else:
        I0 = np.asarray(start, dtype=np.float64)
        if I0.shape != (o, model.spec.interaction_dim):
            raise BayesmotionError(f"start must be a trial index, 'prior' or an array of shape "
                                   f"{(o, model.spec.interaction_dim)}, got {I0.shape}")
        r, desc = start_trial(model, coords, None), "given latent state"
    if dynamics_style == "registered":
        f, w = registered_factor(coords)
        if not _is_vertex(w):
            return _registered(model, P, coords, f, w, n_frames, n_samples, start, seed,
                               sample_memory, lookahead)
        dynamics_style = "requested"  # at a level a registered rollout is the plain one
    paths = latent_paths(model, P, coords, I0, n_frames, n_samples, seed, sample_memory,
                         lookahead, dynamics_style)
    mean = _map_and_decode(model, paths.P, jnp.asarray(paths.I), paths.int_s, r)
    samples = sample_var = None
    if n_samples:
        samples = {"I": paths.I_s, **_map_and_decode_samples(model, paths.P,
                                                             jnp.asarray(paths.I_s),
                                                             paths.int_s, r)}
        sample_var = {k: v.var(0) for k, v in samples.items()}
    I = paths.I
    I_var = paths.I_var[:, None] * np.ones_like(I)
    return Rollout(fps=model.fps, styles=coords,
                   extrapolated=any(is_extrapolated(c) for c in coords.values()), start=desc,
                   n_observed=o, I=I, I_var=I_var, skeletons=mean.pop("skeletons"),
                   samples=samples, sample_var=sample_var, **mean)


REGISTER_MAX_FRAMES = 4000
"""The longest registered rollout: its warps keep a table of (2 T) x (4 T) one-byte steps per
level (128 MB at 4,000 frames)."""


def _registered(model, P, coords: dict, f: str, w: np.ndarray, n_frames: int, n_samples: int,
                start, seed: int, sample_memory: int, lookahead: float) -> Rollout:
    """``generate(dynamics_style="registered")`` between levels of factor ``f`` (coordinates
    ``w``): each level with weight rolls out at its own vertex from one of its own training
    trials, and the levels' paths are registered in time and blended by the coordinates in
    every layer (:mod:`bayesmotion.model.registration`)."""
    if start is not None and not isinstance(start, int | np.integer):
        raise BayesmotionError("a registered rollout starts each level from one of its own "
                               "training trials: give start as a trial index or None")
    if n_frames > REGISTER_MAX_FRAMES:
        raise BayesmotionError(f"a registered rollout is at most {REGISTER_MAX_FRAMES} frames "
                               f"(its time warps grow with the square of the length), got "
                               f"{n_frames}")
    levels = [int(k) for k in np.flatnonzero(np.abs(w) > 1e-12)]
    ref = _reference_level(model, f, w, levels, start)
    r = int(start) if start is not None else _level_trial(model, coords, f, ref)
    trials = {k: r if k == ref else _level_trial(model, coords, f, k, like=r) for k in levels}
    o, A = model.spec.order, model.n_actors
    n_ref = 2 * n_frames + o + 2  # the blend's timing covers n_frames at any pace ratio
    per_level = []
    for n, k in enumerate(sorted(levels, key=lambda k: k != ref)):  # the reference first
        L = n_ref if k == ref else REG_MAX_SLOPE * n_ref
        vc = {g: np.broadcast_to(np.eye(c.shape[1])[k] if g == f else c[0], (L, c.shape[1]))
              for g, c in coords.items()}
        lp = latent_paths(model, P, vc, model.latents(trials[k])["I"][:o], L, n_samples,
                          seed + n, sample_memory, lookahead, "requested")
        per_level.append((k, _level_layers(lp, L, A, n_samples)))
    per_level.sort(key=lambda kv: kv[0])
    layers = [lv for _, lv in per_level]
    times = registration([np.concatenate(list(lv["Y"]), axis=1) for lv in layers],
                         w[levels], levels.index(ref), n_frames, model.fps)
    # frames read only from every level's observed start frames are observed
    n_obs = int(np.argmin(np.all(np.stack(times) <= o - 1, axis=0).tolist() + [False]))

    def mix(key, axis=0, power=1):
        return reg_blend([lv[key] for lv in layers], times, w[levels], axis, power)

    mean = decode_mean(model, mix("X", 1), mix("X_var", 0, 2), mix("Y", 1),
                       mix("Y_var", 1, 2), r, n_observed=n_obs)
    samples = sample_var = None
    if n_samples:
        Y_s = mix("Y_s", 2)
        samples = {"I": mix("I_s", 1), "X": mix("X_s", 2), "Y": Y_s,
                   **decode_samples(model, Y_s, r)}
        sample_var = {k: v.var(0) for k, v in samples.items()}
    I, I_var = mix("I"), mix("I_var", 0, 2)
    I_var[:n_obs] = 0.0
    names = ", ".join(f"{model.levels[f][k]} from trial {trials[k]} "
                      f"({model.trials[trials[k]].name})" for k in levels)
    return Rollout(fps=model.fps, styles=coords,
                   extrapolated=any(is_extrapolated(c) for c in coords.values()),
                   start=f"registered blend of {f} levels: {names}", n_observed=n_obs, I=I,
                   I_var=I_var[:, None] * np.ones_like(I), skeletons=mean.pop("skeletons"),
                   samples=samples, sample_var=sample_var, **mean)


def _level_layers(lp: LatentPaths, L: int, A: int, n_samples: int) -> dict:
    """One level's latent paths mapped down: I, X (A, L, Q_X), Y (A, L, D) and their
    variances; with samples, I_s, X_s (S, A, L, Q_X) and Y_s (S, A, L, D)."""
    layers_out, X_var = map_down(lp.P, jnp.asarray(lp.I), lp.int_s, A)
    lv = {"I": lp.I, "I_var": lp.I_var, "X_var": np.asarray(X_var) * np.ones(L),
          "X": np.stack([np.asarray(x) for x, _, _ in layers_out]),
          "Y": np.stack([np.asarray(y) for _, y, _ in layers_out]),
          "Y_var": np.stack([np.asarray(v) * np.ones(L) for _, _, v in layers_out])}
    if n_samples:
        outs = jax.vmap(lambda I: map_down_mean(lp.P, I, lp.int_s, A))(jnp.asarray(lp.I_s))
        lv["I_s"] = lp.I_s
        lv["X_s"] = np.stack([np.asarray(x) for x, _ in outs], axis=1)
        lv["Y_s"] = np.stack([np.asarray(y) for _, y in outs], axis=1)
    return lv


def _is_vertex(w: np.ndarray) -> bool:
    return bool(np.sum(np.abs(w) > 1e-12) == 1 and np.isclose(w.max(), 1.0))


def registered_factor(coords: dict) -> tuple[str, np.ndarray]:
    """The one factor a registered rollout blends, and its (constant) coordinates (K,); the
    other factors must be at a level. Raises BayesmotionError for coordinates that change
    along the rollout, more than one factor between levels, or no level with weight."""
    for g, c in coords.items():
        if not np.allclose(c, c[0]):
            raise BayesmotionError(f"a registered rollout blends constant coordinates; {g} "
                                   f"changes along the rollout (a Transition or per-frame "
                                   f"array): use dynamics_style='requested' or 'nearest'")
    mixed = [g for g, c in coords.items() if not _is_vertex(np.asarray(c[0]))]
    if len(mixed) > 1:
        raise BayesmotionError(f"a registered rollout blends one style factor; {mixed} are "
                               f"all between levels")
    f = mixed[0] if mixed else ("emotion" if "emotion" in coords else next(iter(coords)))
    w = np.asarray(coords[f][0], np.float64)
    if not np.any(np.abs(w) > 1e-12):
        raise BayesmotionError(f"{f} coordinates {w.tolist()} give no level any weight")
    return f, w


def _reference_level(model, f: str, w: np.ndarray, levels: list[int], start) -> int:
    """The level whose timeline the blend follows: the given start trial's level when its
    weight is the largest (ties included), else the largest weight's (the first of equal)."""
    if start is not None:
        if not 0 <= start < len(model.trials):
            raise BayesmotionError(f"start trial {start} out of range "
                                   f"(0-{len(model.trials) - 1})")
        label = model.trials[start].labels[f]
        k = model.levels[f].index(label)
        if k in levels and w[k] >= w[levels].max() - 1e-12:
            return k
        raise BayesmotionError(f"start trial {start} is {f} {label!r}, not a level of the "
                               f"largest weight in {w.tolist()}: a registered blend follows "
                               f"the timing of that level's trial")
    return max(levels, key=lambda k: (w[k], -k))


def _level_trial(model, coords: dict, f: str, k: int, like: int | None = None) -> int:
    """The training trial level ``k`` of factor ``f`` starts from: the longest of that level
    whose other labels are trial ``like``'s (the same content, ...) with the requested levels
    of the other factors; else the longest with the requested levels; else the longest of
    the level."""
    level = model.levels[f][k]
    want = {g: model.levels[g][int(np.argmax(c[0]))] for g, c in coords.items() if g != f}
    pools = [want, {}]
    if like is not None:
        pools.insert(0, {**{key: v for key, v in model.trials[like].labels.items()
                            if key != f}, **want})
    for extra in pools:
        match = [q for q, t in enumerate(model.trials) if t.labels.get(f) == level
                 and all(t.labels.get(key) == v for key, v in extra.items())]
        if match:
            return max(match, key=lambda q: model.trials[q].n_frames)
    raise BayesmotionError(f"no training trial has {f} {level!r}")


def _check_trained_levels(model, coords: dict) -> None:
    """Refuse weight on a level no training trial has: its (one-hot) style vector is orthogonal
    to every training trial's, so the kernels see no data and the rollout collapses to the
    prior mean (zero) after the start frames."""
    for f, c in coords.items():
        seen = np.asarray(model.data.onehot[f]).sum(0) > 0
        used = np.any(np.abs(np.asarray(c)) > 1e-12, axis=0)
        empty = [model.levels[f][k] for k in np.flatnonzero(used & ~seen)]
        if empty:
            trained = [model.levels[f][k] for k in np.flatnonzero(seen)]
            raise BayesmotionError(f"{f} level(s) {empty} have no training trials in this model "
                                   f"(trained: {trained}); the model cannot generate them")


def _map_and_decode_samples(model, P, I_s, int_s, trial):
    """Samples (S, T, Q_I) -> X, Y, angles, positions, each with a leading sample axis."""
    A = model.n_actors
    outs = jax.vmap(lambda I: map_down_mean(P, I, int_s, A))(I_s)
    X = np.stack([np.asarray(o[0]) for o in outs], axis=1)  # (S, A, T, Q)
    Y = np.stack([np.asarray(o[1]) for o in outs], axis=1)
    return {"X": X, "Y": Y, **decode_samples(model, Y, trial)}


def decode_samples(model, Y, trial: int) -> dict:
    """Poses (S, A, T, D) -> angles (S, A, T, C) and positions (S, A, T, J, 3), on the rig of
    training trial ``trial`` (its bone offsets and root anchor)."""
    angles, positions = [], []
    for a in range(model.n_actors):
        codec, sk = model.codecs[a], model.skeleton(a, trial)
        anchor = _anchor(model, codec, trial, a, Y.shape[2])
        v = np.stack([codec.decode(y, anchor, sk, model.fps).values for y in Y[:, a]])
        angles.append(v)
        positions.append(_positions(sk, v))
    return {"angles": np.stack(angles, 1), "positions": np.stack(positions, 1)}


def _map_and_decode(model, P, I, int_s, trial, with_var=True):
    A = model.n_actors
    if not with_var:  # means alone (no O(N^2) per-frame variances): one "sample", the mean
        return {k: v[0] for k, v in _map_and_decode_samples(model, P, I[None], int_s,
                                                             trial).items()}
    layers_out, X_var = map_down(P, I, int_s, A)
    X = np.stack([np.asarray(l[0]) for l in layers_out])
    Y = np.stack([np.asarray(l[1]) for l in layers_out])
    Y_var = np.stack([np.asarray(l[2]) for l in layers_out])
    return decode_mean(model, X, np.asarray(X_var), Y, Y_var, trial)


def decode_mean(model, X, X_var, Y, Y_var, trial: int, n_observed: int | None = None) -> dict:
    """A mean rollout's layers X (A, T, Q_X), Y (A, T, D) and their isotropic variances
    (X_var broadcastable to (A, T), Y_var (A, T)) -> the rollout's fields: angles, positions
    and their variances on the rig of training trial ``trial``; the first ``n_observed``
    frames (default: the dynamics order; observed) get no variance."""
    A = model.n_actors
    Y_var = np.array(Y_var, dtype=np.float64)
    ang, ang_var, pos, pos_var, sks = [], [], [], [], []
    for a in range(A):
        v, var, sk, rig = decode_actor(model, a, Y[a], Y_var[a], trial)
        rig_values, rig_var, rig_skeleton = rig
        p, pv = _positions_with_var(rig_skeleton, rig_values, rig_var)
        ang.append(v), ang_var.append(var), pos.append(p), pos_var.append(pv), sks.append(sk)
    # the first o frames are observed: no predictive variance there
    o = model.spec.order if n_observed is None else n_observed
    Xv = np.broadcast_to(np.asarray(X_var), (A, X.shape[1])).copy()
    for arr in (Xv, Y_var):
        arr[:, :o] = 0.0
    ang_var = np.stack(ang_var)
    ang_var[:, :o] = 0.0
    pos_var = np.stack(pos_var)
    pos_var[:, :o] = 0.0
    return {"X": X, "X_var": Xv[..., None] * np.ones_like(X), "Y": Y,
            "Y_var": Y_var[..., None] * np.ones_like(Y), "angles": np.stack(ang),
            "angles_var": ang_var, "positions": np.stack(pos), "positions_var": pos_var,
            "skeletons": tuple(sks)}
