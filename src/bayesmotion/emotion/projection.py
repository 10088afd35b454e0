"""Projection of an observed clip into a fitted model's latent spaces (pure JAX densities and
L-BFGS, one jitted call per 100-iteration round), and the Laplace evidence of each emotion
level.

One concept: the MAP latents of one clip under a fixed model -- where the projection starts,
the scaled optimiser (over the whole density or a part of it), and the Hessian it is judged
by -- kept together because the starts, the scaling and the evidence share the same density
and its banded curvature.

The clip's latents X*, I* and its free style coordinates are found by MAP of the clip's
predictive log-density (:func:`bayesmotion.emotion.density.clip_log_density`) with the model fixed,
starting from the latents of the nearest training frames.

``project_levels`` answers "which emotion level explains the clip" as a Bayesian model choice:
for each level k the emotion is held at k's style vector and the latents are projected; the
level's evidence is the Laplace approximation of the latents' marginal likelihood

    log p(Y* | e_k) ~= log p(Y*, X^_k, I^_k | e_k) + (d / 2) log(2 pi) - (1 / 2) log det H_k

with H_k the Hessian of -log p over the d latent coordinates of the clip's frames (and any other
free style) at the level's optimum. Unlike the best optimum of a joint search over latents and
style, it compares every level at its own optimum: a joint search can stop at a mixed-style
point far below the optimum the density has with the emotion held at one level.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jax.flatten_util import ravel_pytree

from bayesmotion.emotion.density import clip_log_density, clip_terms
from bayesmotion.gp.densities import LOG_2PI
from bayesmotion.model.params import STYLE_PREFIX, simplex_to_style, style_log_prior
from bayesmotion.model.predict import Predictor, restrict_to_styles
from bayesmotion.optim import lbfgs

ROUND_ITER = 100  # L-BFGS iterations between re-estimates of the diagonal scaling
HVP_CHUNK = 64  # Hessian-vector products per vmapped batch
# probes per call of the compiled Hessian-vector products (:func:`_hvp_rows`): the diagonal's
# probes and the banded Hessian's (more of them) share one program
HVP_BLOCK = 8
# default sd of the jitter of project_levels' starts, in latent units: none, the nearest-frame
# latents exactly (benchmarks/results/projection_starts.json measured jittered starts at 0.02)
START_JITTER = 0.0
STATIC_ARGS = ("int_factors", "dyn_factors", "init_var")


PARTS = ("all", "bottom", "upper")


def _neg_part(P, params, Ys, mask, fixed, conc, int_factors, dyn_factors, init_var,
              part: str = "all"):
    """-log p of the clip (``part="all"``), or of a part of it: "bottom", the bottom layer's
    term alone (a function of X* only); "upper", the interaction and dynamics terms with the
    free styles' prior (no X*-only term). Under ``jit`` the terms a part leaves out are not
    computed."""
    if part == "all":
        return -clip_log_density(P, params, Ys, mask, fixed, conc, int_factors, dyn_factors,
                                 init_var)
    b, i, d = clip_terms(P, params, Ys, mask, fixed, int_factors, dyn_factors, init_var)
    total = b if part == "bottom" else i + d + style_log_prior(params, conc)
    return -jnp.where(jnp.isnan(total), -jnp.inf, total)


def _subtree(params: dict, keys) -> dict:
    return dict(params) if keys is None else {k: params[k] for k in keys}


@partial(jax.jit, static_argnames=STATIC_ARGS)
def _neg_value_and_grad(params, P, Ys, mask, fixed, conc, int_factors, dyn_factors, init_var):
    f = lambda p: -clip_log_density(P, p, Ys, mask, fixed, conc, int_factors, dyn_factors,
                                    init_var)
    return jax.value_and_grad(f)(params)


@partial(jax.jit, static_argnames=STATIC_ARGS + ("keys", "part"))
def _scaled_lbfgs(x, scale, n_iter, template, P, Ys, mask, fixed, conc, int_factors,
                  dyn_factors, init_var, keys=None, part="all") -> lbfgs.LbfgsResult:
    """At most ``n_iter`` L-BFGS iterations on -log p (or its ``part``, :func:`_neg_part`)
    over z = x / scale, in one call. x holds the entries ``keys`` of ``template`` (all: None),
    raveled; the other entries are held at their values in ``template``. The result's x is
    unscaled."""
    unravel = ravel_pytree(_subtree(template, keys))[1]
    f = lambda z: _neg_part(P, {**template, **unravel(z * scale)}, Ys, mask, fixed, conc,
                            int_factors, dyn_factors, init_var, part)
    r = lbfgs.minimize(jax.value_and_grad(f), x / scale, n_iter)
    return r._replace(x=r.x * scale)


def init_latents(model, Ys, B, rows=None):
    """Latents of the nearest training frame (in pose space) for every clip frame, among the
    training frames ``rows`` (default all)."""
    train = np.concatenate([np.asarray(Y) for Y in model.data.Y], axis=1)
    rows = np.arange(train.shape[0]) if rows is None else np.asarray(rows)
    train = train[rows]
    clip = np.concatenate(Ys, axis=1)
    d = (np.sum(clip**2, 1)[:, None] + np.sum(train**2, 1)[None] - 2 * clip @ train.T)
    nearest = rows[np.argmin(d, 1)]
    T = clip.shape[0]
    X = np.asarray(model.params["X"])[:, nearest]
    I = np.asarray(model.params["I"])[nearest]
    pad = B - T
    X = np.concatenate([X, np.repeat(X[:, -1:], pad, 1)], 1)
    I = np.concatenate([I, np.repeat(I[-1:], pad, 0)], 0)
    return X, I, nearest


def projection_starts(model, Ys, B, inferred, conc, mode: str) -> list[dict]:
    """Starting points of the projection: latents and free styles.

    ``"nearest"``: one start, the latents of the nearest training frames and each free style
    near the level most of those frames have. ``"levels"``: that start, and one per emotion
    level k with the latents of the nearest frames among level k's training trials and the
    emotion near vertex k -- the clip explained as each emotion in turn. The projection keeps
    the best optimum, so its objective is never worse than from "nearest" alone. The clip
    density is multimodal in (latents, style): a single start can end above the optimum the
    same density has with the emotion held at another vertex.
    """
    groups = [None]
    if mode == "levels" and "emotion" in model.data.onehot:
        groups += [g for g in _level_rows(model) if g is not None]
    return [_start_params(model, Ys, B, rows, inferred, conc) for rows in groups]


def _start_params(model, Ys, B, rows, factors, conc) -> dict:
    """Latents of the nearest training frames among ``rows`` and each free style in
    ``factors`` near the level most of those frames have (the prior mean for an unlabelled
    factor)."""
    X0, I0, nearest = init_latents(model, Ys, B, rows)
    params = {"X": jnp.asarray(X0), "I": jnp.asarray(I0)}
    for f in factors:
        start = (_style_start(model, f, conc[f], nearest) if f in model.data.onehot
                 else conc[f] / conc[f].sum())
        params[STYLE_PREFIX + f] = simplex_to_style(jnp.asarray(start)[None])[0]
    return params


def _style_start(model, factor: str, conc, nearest) -> np.ndarray:
    """Start of a free style on the simplex: 0.85 on the level most of the nearest training
    frames have (0.15 spread over the others), so that the start matches its latents.

    From the prior mean (a uniform mix, which scales every style-weighted prediction down)
    the projection can settle in a mixed-style optimum that explains the clip worse than any
    level does; started near the level its latents come from, it starts where that level's
    predictions are whole."""
    K = conc.size
    level = np.argmax(model.data.onehot[factor], 1)[model.data.trial_of_frame[nearest]]
    v = np.full(K, 0.15 / max(K - 1, 1))
    v[np.bincount(level, minlength=K).argmax()] = 0.85
    return v



def minimize_scaled(params, args, statics, max_iter, round_iter: int = ROUND_ITER, *,
                    keys=None, part: str = "all"):
    """L-BFGS on -log p in coordinates scaled by |diag H|^(-1/2), the diagonal recomputed
    exactly (:func:`_diag_probes`) every ``round_iter`` iterations; each round is one jitted
    call (bayesmotion.optim.lbfgs). With ``keys`` (a tuple of entries of ``params``) only
    those entries move, the others held; ``part`` minimises a part of -log p instead
    (:func:`_neg_part`: "bottom" or "upper").

    The clip density is badly conditioned: the bottom layer's curvature in X is orders of
    magnitude above the dynamics' in I. Unscaled, 1000 iterations from the nearest training
    frames got a generated neutral handshake to -7,303 with the emotion held at neutral, where
    the generating latents alone score -9,884; scaled, 300 iterations reach -9,491 (scipy's
    L-BFGS-B). Returns (params, a scipy ``OptimizeResult`` built from the last round:
    ``fun`` (inf if never finite), ``nit`` and ``nfev`` summed over the rounds, ``status`` and
    ``message`` from bayesmotion.optim.lbfgs; no ``jac``)."""
    if part not in PARTS:
        raise ValueError(f"part must be one of {PARTS}, got {part!r}")
    keys = None if keys is None else tuple(keys)
    sub = _subtree(params, keys)
    x0, unravel = ravel_pytree(sub)
    x = np.asarray(x0, np.float64)
    V = jnp.asarray(_diag_probes(sub, args[0].dyn_lags.shape[0] + 1))
    done, nfev, res = 0, 0, None
    full = lambda v: {**params, **unravel(jnp.asarray(v))}
    while done < max_iter:
        a = np.abs(_diag_flat(full(x), V, args, statics, keys, part))
        scale = diagonal_scale(a)
        n = min(round_iter, max_iter - done)
        r = _scaled_lbfgs(jnp.asarray(x), jnp.asarray(scale), n, params, *args, **statics,
                          keys=keys, part=part)
        x = np.asarray(r.x, np.float64)
        nit, status = int(r.nit), int(r.status)
        done += max(nit, 1)
        nfev += int(r.nfev)
        res = scipy.optimize.OptimizeResult(
            fun=float(r.fun), nfev=nfev, status=status, message=lbfgs.MESSAGES[status],
            success=status in (lbfgs.CONVERGED_GTOL, lbfgs.CONVERGED_FTOL))
        if status != lbfgs.MAX_ITER:  # converged (or no progress) at this scaling
            break
    res.x, res.nit = x, done
    return full(x), res


@partial(jax.jit, static_argnames=STATIC_ARGS)
def _scaled_lbfgs_many(x, scale, n_iter, template, P, Ys, mask, fixed, conc, int_factors,
                       dyn_factors, init_var) -> lbfgs.LbfgsResult:
    """:func:`_scaled_lbfgs` for a batch of jobs (leading axis of every argument but
    ``template``), one program: the jobs' L-BFGS loops run side by side."""
    one = lambda *a: _scaled_lbfgs(a[0], a[1], a[2], template, *a[3:], int_factors, dyn_factors,
                                   init_var)
    return jax.vmap(one)(x, scale, n_iter, P, Ys, mask, fixed, conc)


@partial(jax.jit, static_argnames=STATIC_ARGS)
def _hvps_many(params, V, P, Ys, mask, fixed, conc, int_factors, dyn_factors, init_var):
    """:func:`_hvps` for a batch of jobs (leading axis of every argument but ``V``)."""
    one = lambda p, *a: _hvps(p, V, *a, int_factors, dyn_factors, init_var)
    return jax.vmap(one)(params, P, Ys, mask, fixed, conc)


def _signature(tree) -> tuple:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return treedef, tuple((np.shape(v), jnp.result_type(v)) for v in leaves)


def _stack(trees):
    return jax.tree_util.tree_map(lambda *v: jnp.stack([jnp.asarray(u) for u in v]), *trees)


def batch_jobs() -> bool:
    """Whether :func:`minimize_scaled_many` batches by default: on an accelerator, where the
    L-BFGS loop's latency sets the time, not on a CPU, where its arithmetic does and a batch
    runs every job until the slowest one stops."""
    return jax.default_backend() != "cpu"


def minimize_scaled_many(jobs, statics, max_iter, round_iter: int = ROUND_ITER,
                         batch: bool | None = None) -> list:
    """``[minimize_scaled(params, args, statics, max_iter) for params, args in jobs]``; with
    ``batch`` (default :func:`batch_jobs`) the jobs whose arrays have the same shapes run
    together under ``vmap``: each round is one program for the whole group, so K emotion
    levels cost one dispatch per round instead of K.

    Each job keeps its own diagonal scaling, iteration count and stopping; a job that stops
    early is carried along unchanged. Batched arithmetic may round differently from one job
    at a time, so optima can differ in the last digits. On this 2-core CPU a batch of the 4
    levels of a held-out built-in handshake took a median 2.84 s against 2.16 s one at a time,
    hence no batching there by default (``benchmarks/results/device_timings_cpu.json``)."""
    if not (batch_jobs() if batch is None else batch):
        return [minimize_scaled(p, a, statics, max_iter, round_iter) for p, a in jobs]
    groups: dict = {}
    for j, job in enumerate(jobs):
        groups.setdefault(_signature(job), []).append(j)
    out = [None] * len(jobs)
    for idx in groups.values():
        if len(idx) == 1:
            out[idx[0]] = minimize_scaled(*jobs[idx[0]], statics, max_iter, round_iter)
            continue
        params0 = jobs[idx[0]][0]
        unravel = ravel_pytree(params0)[1]
        x = np.stack([np.asarray(ravel_pytree(jobs[j][0])[0], np.float64) for j in idx])
        args = _stack([jobs[j][1] for j in idx])
        V = jnp.asarray(_diag_probes(params0, jobs[idx[0]][1][0].dyn_lags.shape[0] + 1))
        n = len(idx)
        done = np.zeros(n, int)
        nfev = np.zeros(n, int)
        active = np.ones(n, bool)
        fun = np.full(n, np.inf)
        status = np.full(n, lbfgs.MAX_ITER)
        while active.any():
            HV = _hvps_many(jax.vmap(unravel)(jnp.asarray(x)), V, *args, **statics)
            a = np.abs(np.sum(np.asarray(V)[None] * np.asarray(HV), 1))  # (n, d) diag H
            scale = diagonal_scale(a)
            steps = np.where(active, np.minimum(round_iter, max_iter - done), 0)
            r = _scaled_lbfgs_many(jnp.asarray(x), jnp.asarray(scale), jnp.asarray(steps),
                                   params0, *args, **statics)
            rx, rnit, rst = np.asarray(r.x), np.asarray(r.nit), np.asarray(r.status)
            rf, rnfev = np.asarray(r.fun), np.asarray(r.nfev)
            for i in np.flatnonzero(active):
                x[i] = rx[i]
                done[i] += max(int(rnit[i]), 1)
                nfev[i] += int(rnfev[i])
                fun[i], status[i] = float(rf[i]), int(rst[i])
                if status[i] != lbfgs.MAX_ITER or done[i] >= max_iter:
                    active[i] = False
        for i, j in enumerate(idx):
            st = int(status[i])
            res = scipy.optimize.OptimizeResult(
                fun=float(fun[i]), nfev=int(nfev[i]), status=st, message=lbfgs.MESSAGES[st],
                success=st in (lbfgs.CONVERGED_GTOL, lbfgs.CONVERGED_FTOL))
            res.x, res.nit = x[i].copy(), int(done[i])
            out[j] = (unravel(jnp.asarray(x[i])), res)
    return out


def diagonal_scale(a: np.ndarray) -> np.ndarray:
    """Coordinate scales |diag H|^(-1/2) from ``a`` = |diag H| (last axis; one row per job),
    entries below 1e-6 of their row's largest floored there, zero entries unscaled."""
    top = a.max(-1, keepdims=True) if a.size else np.ones(a.shape[:-1] + (1,))
    top = np.where(top > 0, top, 1.0)
    return np.where(a > 0, 1.0 / np.sqrt(np.maximum(a, 1e-6 * top)), 1.0)


def _diag_flat(params, V, args, statics, keys=None, part="all") -> np.ndarray:
    """Exact diag of the Hessian of -log p (or its ``part``) over the entries ``keys`` of
    ``params`` (all: None; flat), from the probes ``V`` of :func:`_diag_probes`."""
    return np.sum(np.asarray(V) * _hvp_rows(params, V, args, statics, keys, part), 0)


def _hvp_rows(params, V, args, statics, keys=None, part="all") -> np.ndarray:
    """:func:`_hvps` of the rows of ``V`` (n, d), in calls of :data:`HVP_BLOCK` rows (the last
    padded with zeros), so that every probe set over the same parameters (the diagonal's, the
    banded Hessian's) runs one compiled program instead of one per probe count."""
    V = np.asarray(V, dtype=np.float64)
    n, d = V.shape
    padded = np.zeros((-(-n // HVP_BLOCK) * HVP_BLOCK, d))
    padded[:n] = V
    return np.concatenate([
        np.asarray(_hvps(params, jnp.asarray(padded[i:i + HVP_BLOCK]), *args, **statics,
                         keys=keys, part=part), dtype=np.float64)
        for i in range(0, len(padded), HVP_BLOCK)])[:n]


def diag_hessian(params, args, statics) -> dict:
    """Exact diagonal of the Hessian of -log p over ``params``, shaped like ``params``, from
    A Q_X + (o + 1) Q_I + n_style Hessian-vector products (:func:`_diag_probes`)."""
    V = jnp.asarray(_diag_probes(params, args[0].dyn_lags.shape[0] + 1))
    return ravel_pytree(params)[1](jnp.asarray(_diag_flat(params, V, args, statics)))


def _diag_probes(params, period: int) -> np.ndarray:
    """Probe vectors (n, d) whose Hessian products give diag H exactly.

    X*_a,t shares density terms only with latents of its own frame (the bottom and interaction
    terms are per frame), so one probe per actor and coordinate summed over every frame; I*_t
    shares the dynamics terms with frames up to ``order`` away, so one probe per coordinate and
    residue of the frame index mod ``period`` (order + 1); one probe per style coordinate. With
    probes V_p, diag H = sum_p V_p * (H V_p): A Q_X + (order + 1) Q_I + n_style products,
    whatever the clip length.
    """
    probes = []
    for key, v in params.items():
        shape = np.shape(v)
        if key == "X":
            probes.extend((key, (a, slice(None), q)) for a in range(shape[0])
                          for q in range(shape[2]))
        elif key == "I":
            probes.extend((key, (slice(c, shape[0], period), q)) for c in range(period)
                          for q in range(shape[1]))
        else:
            probes.extend((key, (j,)) for j in range(int(np.prod(shape))))
    out = []
    for key, idx in probes:
        tree = {k: np.zeros(np.shape(v)) for k, v in params.items()}
        tree[key][idx] = 1.0
        out.append(np.asarray(ravel_pytree({k: jnp.asarray(t) for k, t in tree.items()})[0]))
    return np.stack(out)


def project(params, args, statics, max_iter, inferred, conc):
    """MAP projection. When a style factor other than the emotion (the couple, say) is inferred
    too, one start per level of the first such factor (its style vector near that level's
    vertex) and the best optimum is kept: from the prior mean the latents can settle in an
    optimum that explains the clip with the wrong couple *and* the wrong emotion (a neutral c1
    training trial came out angry, P = 0.75, from one start)."""
    fits = minimize_scaled_many([(p, args) for p in other_starts(params, inferred, conc)],
                                statics, max_iter)
    return best_fit(fits)


def other_starts(params, inferred, conc) -> list[dict]:
    """The starts :func:`project` runs from ``params``: itself, or one per level of the first
    inferred factor other than the emotion."""
    others = [f for f in inferred if f != "emotion"]
    if not others:
        return [params]
    f = others[0]
    K = conc[f].size
    starts = []
    for k in range(K):
        v = np.full(K, 0.1 / max(K - 1, 1))
        v[k] = 0.9
        starts.append({**params, STYLE_PREFIX + f: simplex_to_style(jnp.asarray(v)[None])[0]})
    return starts


def best_fit(fits):
    """The (params, result) of lowest objective, the first on ties."""
    best = None
    for out in fits:
        if best is None or out[1].fun < best[1].fun:
            best = out
    return best


@partial(jax.jit, static_argnames=STATIC_ARGS + ("keys", "part"))
def _hvps(params, V, P, Ys, mask, fixed, conc, int_factors, dyn_factors, init_var, keys=None,
          part="all"):
    """(n, d) rows H v for each row v of ``V``, H the Hessian of -log p (or its ``part``,
    :func:`_neg_part`) over the entries ``keys`` of ``params`` (all: None; ravel_pytree
    order), the others held: one linearisation of the gradient, then the products in chunks
    of at most 64 (memory bounded by the chunk, not by n)."""
    z0, unravel = ravel_pytree(_subtree(params, keys))
    f = lambda z: _neg_part(P, {**params, **unravel(z)}, Ys, mask, fixed, conc, int_factors,
                            dyn_factors, init_var, part)
    _, hvp = jax.linearize(jax.grad(f), z0)
    n, d = V.shape
    chunk = -(-n // -(-n // HVP_CHUNK))  # equal chunks of at most 64: little padding
    m = -(-n // chunk) * chunk
    V = jnp.concatenate([V, jnp.zeros((m - n, d), V.dtype)])
    return jax.lax.map(jax.vmap(hvp), V.reshape(-1, chunk, d)).reshape(m, d)[:n]


def _frame_layout(params):
    """Per flat coordinate (ravel_pytree order): its frame (-1 for a style coordinate) and its
    index within the frame (I first, then each actor's X; -1 for a style)."""
    Q_I = params["I"].shape[1]
    frame, local = {}, {}
    for k, v in params.items():
        sh = np.shape(v)
        if k == "I":
            frame[k] = np.broadcast_to(np.arange(sh[0])[:, None], sh)
            local[k] = np.broadcast_to(np.arange(sh[1])[None], sh)
        elif k == "X":
            frame[k] = np.broadcast_to(np.arange(sh[1])[None, :, None], sh)
            local[k] = np.broadcast_to(Q_I + np.arange(sh[0])[:, None, None] * sh[2]
                                       + np.arange(sh[2])[None, None], sh)
        else:
            frame[k] = local[k] = np.full(sh, -1)
    flat = lambda t: np.rint(np.asarray(ravel_pytree(
        {k: jnp.asarray(v, jnp.float64) for k, v in t.items()})[0])).astype(int)
    return flat(frame), flat(local)


def banded_hessian(params, args, statics) -> np.ndarray:
    """Dense Hessian of -log p over ``params`` from A Q_X + (2 o + 1) Q_I + n_style
    Hessian-vector products instead of d (o the dynamics order, Q_X and Q_I the latent
    dimensions, A the actors).

    The bottom and interaction terms are per frame and the dynamics terms couple I* over o
    lags, so the latent block of H is banded, and the X* columns meet only their own frame. A
    probe summing X* coordinate (a, q) over every frame returns, in the row of any latent of
    frame t, the entry against X*_a,t,q; a probe summing I* coordinate j over the frames
    congruent to c mod 2 o + 1 returns the entry against the one such frame within o of t.
    Style coordinates couple with everything and get one probe each."""
    frame, local = _frame_layout(params)
    o = args[0].dyn_lags.shape[0]
    Q_I = params["I"].shape[1]
    d = frame.size
    lat = np.flatnonzero(frame >= 0)
    sty = np.flatnonzero(frame < 0)
    L = int(local.max()) + 1
    B = int(frame.max()) + 1
    where = np.full((B, L), -1)
    where[frame[lat], local[lat]] = lat
    rows, probes = [], []
    for j in range(L):
        period = 2 * o + 1 if j < Q_I else 1  # local index: I first, then each actor's X
        for c in range(period):
            v = np.zeros(d)
            v[lat[(frame[lat] % period == c) & (local[lat] == j)]] = 1.0
            probes.append(v)
            rows.append((period, c, j))
    for i in sty:
        v = np.zeros(d)
        v[i] = 1.0
        probes.append(v)
    HV = _hvp_rows(params, np.stack(probes), args, statics)
    H = np.zeros((d, d))
    f = frame[lat]
    for r, (period, c, j) in enumerate(rows):
        delta = (c - f) % period
        delta = np.where(delta > period // 2, delta - period, delta)
        t = f + delta
        ok = (t >= 0) & (t < B)
        H[lat[ok], where[t[ok], j]] = HV[r, lat[ok]]
    for r, i in enumerate(sty):
        H[:, i] = HV[len(rows) + r]
        H[i, :] = HV[len(rows) + r]
    return H


def laplace_log_evidence(params, args, statics, T: int, value: float | None = None
                         ) -> tuple[float, dict]:
    """Laplace approximation of log of the integral of p(Y*, X*, I*, s_free) over the latents
    of the clip's T real frames and the free styles in ``params``, around their optimum
    ``params``.

    Padded frames (beyond T) carry no density, so their rows are dropped. Directions of the
    Hessian that are not positive (an optimum not reached: L-BFGS stopped at its iteration
    limit) are floored at 1e-6 of the largest curvature and counted in ``info``.
    ``value``: log p at ``params`` when already known (a projection's L-BFGS ends with it:
    minus its ``fun``), which spares compiling the density's value on its own.
    Returns (log evidence, info: objective, logdet, dim, n_nonpositive).
    """
    H = banded_hessian(params, args, statics)
    B = params["I"].shape[0]
    frames = np.arange(B) < T
    real = {k: np.broadcast_to(frames[None, :, None] if k == "X" else frames[:, None], v.shape)
            if k in ("X", "I") else np.ones(v.shape, bool) for k, v in params.items()}
    keep = np.asarray(ravel_pytree({k: jnp.asarray(v, jnp.float64)
                                    for k, v in real.items()})[0]) > 0.5
    H = H[np.ix_(keep, keep)]
    ev = np.linalg.eigvalsh(0.5 * (H + H.T))
    floor = 1e-6 * max(float(ev.max()), 1e-300)
    logdet = float(np.sum(np.log(np.maximum(ev, floor))))
    if value is None:
        value = float(-_neg_value_and_grad(params, *args, **statics)[0])
    d = int(keep.sum())
    return value + 0.5 * d * LOG_2PI - 0.5 * logdet, {
        "log_density": value, "logdet": logdet, "dim": d, "n_nonpositive": int(np.sum(ev <= 0))}


def _level_rows(model) -> list:
    """Training frame rows of each emotion level (None: the level has no training frame, its
    projection starts from the nearest frames overall)."""
    level = np.argmax(model.data.onehot["emotion"], 1)[model.data.trial_of_frame]
    return [g if g.size else None
            for g in (np.flatnonzero(level == k) for k in range(len(model.levels["emotion"])))]


def seen_predictor(P: Predictor, fixed: dict, int_factors, dyn_factors) -> Predictor:
    """P without the style cells a clip cannot see, whatever its free styles: the same density,
    less work (:func:`bayesmotion.model.predict.restrict_to_styles`, exact).

    A factor in ``fixed`` (factor -> its (K_f,) kernel style vector) keeps the cells whose
    style meets that vector; any other factor is free and keeps every cell (a row of ones
    meets every one-hot training style). With the emotion held at one level and the couple
    given, a built-in handshake clip sees 1 of the 8 cells of the interaction and dynamics
    layers; a walk held at one emotion, 1 of 4.
    """
    def rows(factors):
        return [jnp.asarray(fixed[f])[None] if f in fixed
                else jnp.ones((1, P.level_vectors[f].shape[0])) for f in factors]

    R = restrict_to_styles(P, rows(dyn_factors), rows(int_factors))
    if (_n_cells(R.inter) == _n_cells(P.inter) and _n_cells(R.dyn) == _n_cells(P.dyn)):
        return P  # nothing dropped: keep the shapes the model's programs compiled for
    return R


def _n_cells(fit) -> int | None:
    return None if fit.rows is None else int(np.shape(fit.rows)[0])


def _jittered(params: dict, sd: float, rng: np.random.Generator) -> dict:
    """``params`` with N(0, sd^2) added to every latent coordinate (X and I); styles kept."""
    out = dict(params)
    for k in ("X", "I"):
        out[k] = params[k] + jnp.asarray(sd * rng.standard_normal(np.shape(params[k])))
    return out


def staged_bottom(params, args, statics, max_iter) -> jnp.ndarray:
    """The first stage of a staged start: X* minimising the bottom layer's term alone (no
    style enters it, so one X* serves every level), from ``params``' X."""
    return minimize_scaled(params, args, statics, max_iter, keys=("X",), part="bottom")[0]["X"]


def staged_upper(params, args, statics, max_iter) -> dict:
    """The second stage of a staged start: with X* held, I* and the free styles minimising the
    interaction and dynamics terms (and the styles' prior), from ``params``."""
    keys = tuple(k for k in params if k != "X")
    return minimize_scaled(params, args, statics, max_iter, keys=keys, part="upper")[0]


def project_levels(model, P, Ys, B, T, args, statics, max_iter, inferred, conc,
                   n_starts: int = 1, seed: int = 0, jitter: float = START_JITTER,
                   staged: bool = False):
    """One projection per emotion level k with the emotion held at k's style vector, from the
    latents of the nearest frames of k's training trials; the other free styles (the couple,
    when not given) are projected with it. Each level's density drops the style cells it
    cannot see (:func:`seen_predictor`). With ``n_starts`` > 1 a level is projected from that
    start and from ``n_starts`` - 1 copies of it jittered by N(0, ``jitter``^2) in every latent
    coordinate (seeded by ``seed`` and the level, so the starts of ``n_starts`` = k >= 2 are
    the first k of any larger ``n_starts``); with one start, ``jitter`` > 0 jitters that
    start, which is then the second start of any larger ``n_starts``.
    The best optimum is kept: the clip density is multimodal in the latents.

    ``staged`` starts each level in two stages before the joint projection: the
    latents of the nearest training frames put every frame's X* far from where the bottom layer
    explains it and make I* jump between training trials (on a held-out Bandai walk the start
    scored -log p of 10^6 against 10^3 at the optimum), and L-BFGS spent hundreds of
    iterations of the full density getting back. First X* by the bottom term alone
    (:func:`staged_bottom`, from the nearest frames overall; shared by the levels), then per
    level I* and the free styles by the other terms with X* held (:func:`staged_upper`, from
    the level's nearest frames; each evaluation skips the bottom layer, the most expensive
    term); the joint projection starts there. ``benchmarks/projection_starts.py`` measures
    both starts on the same folds. Returns per level:
    (params, scipy result, log evidence, info) -- see :func:`laplace_log_evidence`; info adds
    every start's ``start_objectives`` and ``start_log_evidence``."""
    Pm, Yp, mask, fixed_j, conc_j = args
    others = [f for f in inferred if f != "emotion"]
    conc_o = {f: conc[f] for f in others}
    jobs, owner, level_args = [], [], []
    shared_X = None
    for k, rows in enumerate(_level_rows(model)):
        rng = np.random.default_rng([seed, k])
        params = _start_params(model, Ys, B, rows, others, conc)
        fixed_k = {**fixed_j, "emotion": jnp.asarray(Pm.level_vectors["emotion"][k])}
        Pk = seen_predictor(Pm, fixed_k, statics["int_factors"], statics["dyn_factors"])
        args_k = (Pk, Yp, mask, fixed_k, {f: conc_j[f] for f in others})
        level_args.append(args_k)
        if staged and shared_X is None:
            nearest = _start_params(model, Ys, B, None, others, conc)
            shared_X = staged_bottom({**params, "X": nearest["X"]}, args_k, statics, max_iter)
        staged_starts = None if not staged else [
            staged_upper({**p, "X": shared_X}, args_k, statics, max_iter)
            for p in other_starts(params, others, conc_o)]
        for j in range(n_starts):
            jitter_j = jitter > 0 and (j > 0 or n_starts == 1)
            if staged:
                starts = [_jittered(p, jitter, rng) if jitter_j else p for p in staged_starts]
            else:
                start = _jittered(params, jitter, rng) if jitter_j else params
                starts = other_starts(start, others, conc_o)
            for p in starts:
                jobs.append((p, args_k))
                owner.append((k, j))
    # every level, start and other-style start in one batch: one program per L-BFGS round
    fits = minimize_scaled_many(jobs, statics, max_iter)
    out = []
    for k, args_k in enumerate(level_args):
        best, objectives, evidences = None, [], []
        for j in range(n_starts):
            p, res = best_fit([f for f, o in zip(fits, owner, strict=True) if o == (k, j)])
            log_ev, info = laplace_log_evidence(p, args_k, statics, T, value=-float(res.fun))
            objectives.append(float(res.fun))
            evidences.append(float(log_ev))
            if best is None or res.fun < best[1].fun:
                best = (p, res, log_ev, info)
        p, res, log_ev, info = best
        out.append((p, res, log_ev, {**info, "start_objectives": objectives,
                                     "start_log_evidence": evidences}))
    return out
