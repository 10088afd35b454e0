"""GP predictive distributions of the fitted hierarchy (eq. 13-16).

``condition(model)`` precomputes, for every layer, the inverse Cholesky factor of the training
kernel matrix and the weights ``A = K^-1 outputs``; the result is a pytree, so a posterior can
stack one per draw and ``vmap`` over them. For a new input ``u`` with style ``s``:

    mean(u) = k(u, U)^T A,      var(u) = k(u, u) - |L^-1 k(U, u)|^2      (per output dimension)

(the noise variance is added by callers that predict noisy outputs).

A sparse model (``HGPDM(inducing=M)``) is conditioned through its inducing inputs, which then
stand where the training inputs stand above (U, the weights and the factor of
:mod:`bayesmotion.gp.sparse`): every prediction below serves both unchanged, at O(M) per input
for the mean and O(M^2) for the variance.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_solve

from bayesmotion.gp import densities, kernels, sparse
from bayesmotion.gp.linalg import triangular_inverse
from bayesmotion.model import layers
from bayesmotion.model.logpost import ar_of, constrained, trial_styles
from bayesmotion.model.params import STYLE_PREFIX, style_to_simplex


class LayerFit(NamedTuple):
    """One conditioned GP layer: Linv = L^-1 of the training Gram matrix K = L L^T, and the
    weights A = K^-1 outputs (M, D).

    The inverse factor, not L, so that predictive variances |L^-1 k|^2 are matrix products
    (every core, and batched without LAPACK calls) instead of triangular solves.

    Dense (``rows`` None): Linv is L^-1 (M, M) packed by :func:`pack_lower`. Blocked: when
    the layer's training styles are one-hot, K is block-diagonal over style cells (the style
    factor is exactly 0 across cells, Wang et al. 2007), and so is L^-1; then Linv holds one
    (B, B) inverse factor per cell, (n_cells, B, B), ``rows`` (n_cells, B) each cell's
    training rows and ``mask`` (n_cells, B) 1.0 for real rows, 0.0 for padding. A is (M, D)
    either way. The variance products then cost sum_cells B^2 instead of M^2 per input (8x
    fewer on the built-in handshakes).
    Use :func:`whiten` rather than Linv directly.
    """

    Linv: jnp.ndarray | dict
    A: jnp.ndarray
    rows: jnp.ndarray | None = None
    mask: jnp.ndarray | None = None


def whiten(fit: LayerFit, kx: jnp.ndarray) -> jnp.ndarray:
    """A matrix V with V^T V = kx^T K^-1 kx for cross-covariances kx (M, n): L^-1 kx (M, n)
    for a dense fit; for a blocked fit the cells' L_b^-1 kx_b stacked, (n_cells * B, n)."""
    if fit.rows is None:
        return jnp.concatenate(lower_parts(fit.Linv, kx))
    kb = kx[fit.rows] * fit.mask[..., None]  # (n_cells, B, n); padding rows zero
    return jnp.matmul(fit.Linv, kb).reshape(-1, kx.shape[-1])


class Predictor(NamedTuple):
    """All conditioned layers of a fitted model (a pytree of arrays).

    Attributes:
        dyn_lags: (o, M, Q_I) training inputs of the dynamics GP; dyn_style: per dynamics factor
            (M, K_f) styles of its outputs; dyn: LayerFit (its weights those of the outputs
            less the autoregressive mean); alpha: (2 + o,) or (2 + 2o,) with the linear kernel
            term; ar: (o,) coefficients of the explicit stable autoregressive mean (zeros for
            a model with the paper's linear kernel term instead).
        I: (N, Q_I) interaction inputs; int_style: per interaction factor (N, K_f); inter:
            LayerFit; beta: (3,).
        X: (A, N, Q_X) bottom inputs; bottom_Linv: per actor, the inverse Cholesky factor
            packed by :func:`pack_lower`; bottom_A: per actor (N, D_a) weights (tuples: the
            D_a may differ).
        gamma: (3,).
        level_vectors: factor -> (K_f, K_f), row k the style vector of level k: the identity
            unless the fit learned the style vectors (``optimize_style``). Callers give a new
            input's style as coordinates over the levels; :func:`style_vectors` maps them.
    """

    dyn_lags: jnp.ndarray
    dyn_style: tuple
    dyn: LayerFit
    alpha: jnp.ndarray
    ar: jnp.ndarray
    I: jnp.ndarray
    int_style: tuple
    inter: LayerFit
    beta: jnp.ndarray
    X: jnp.ndarray
    bottom_Linv: tuple
    bottom_A: tuple
    gamma: jnp.ndarray
    level_vectors: dict


def style_vectors(P: Predictor, factors, coords) -> list[jnp.ndarray]:
    """Style coordinates over the levels, (..., K_f) per factor -> the kernels' style vectors
    (coordinates @ level vectors): a label's one-hot coordinates give its learned vector."""
    return [jnp.asarray(c) @ P.level_vectors[f] for f, c in zip(factors, coords, strict=True)]


def whitened_norms(fit: LayerFit, kx: jnp.ndarray) -> jnp.ndarray:
    """kx^T K^-1 kx per column, (n,): the column sums of squares of :func:`whiten`, without
    assembling it."""
    if fit.rows is None:
        return sum(jnp.sum(part * part, 0) for part in lower_parts(fit.Linv, kx))
    v = whiten(fit, kx)
    return jnp.sum(v * v, 0)


def pack_lower(L: jnp.ndarray, depth: int = 2) -> dict:
    """A lower-triangular L as the blocks :func:`lower_parts` multiplies: halved ``depth``
    times, {"a": top-left, "off": bottom-left, "c": bottom-right} down to {"leaf": block}.
    The zero upper blocks are not kept (5/8 of L's entries at depth 2), and each block is its
    own contiguous array, so the products read no strided slices."""
    n = L.shape[0]
    if depth == 0 or n < 128:
        return {"leaf": L}
    h = n // 2
    return {"a": pack_lower(L[:h, :h], depth - 1), "off": L[h:, :h],
            "c": pack_lower(L[h:, h:], depth - 1)}


def lower_parts(packed: dict, k: jnp.ndarray) -> list:
    """L @ k from :func:`pack_lower`'s blocks, as a list of row blocks (concatenated, they are
    L @ k), skipping the zero blocks above the diagonal that a dense product multiplies."""
    if "leaf" in packed:
        return [packed["leaf"] @ k]
    h = packed["off"].shape[1]
    off = packed["off"] @ k[:h]  # added to each row block of the bottom half
    out, r = [], 0
    for part in lower_parts(packed["c"], k[h:]):
        out.append(part + off[r:r + part.shape[0]])
        r += part.shape[0]
    return lower_parts(packed["a"], k[:h]) + out


def _fit_layer(K, outputs, jitter):
    L, _ = densities.safe_cholesky(K, jitter)
    return LayerFit(pack_lower(triangular_inverse(L)), cho_solve((L, True), outputs))


def _fit_blocked(K_of_rows, noise_var, outputs, blocks: densities.Blocks, jitter):
    """:func:`_fit_layer` of a block-diagonal K = blockdiag(K_b) + noise_var I, one cell at a
    time. The jitter is the dense path's, jitter * mean(diag K) over all rows, so the result
    equals the dense fit's (tested). Padding rows get unit variance, no coupling and zero
    output; :func:`whiten` zeroes their cross-covariances."""
    idx, mask = jnp.asarray(blocks.idx), jnp.asarray(blocks.mask)
    Ks = densities.block_matrices(K_of_rows, noise_var, blocks, jitter)
    L = jax.vmap(lambda K: densities.safe_cholesky(K, 0.0)[0])(Ks)
    Yb = jnp.where(mask[..., None], outputs[idx], 0.0)
    Ab = jax.vmap(lambda L, y: cho_solve((L, True), y))(L, Yb)
    real = blocks.mask  # static (NumPy): the real rows' places
    A = jnp.zeros_like(outputs).at[blocks.idx[real]].set(Ab[real])
    Linv = jax.vmap(triangular_inverse)(L)
    return LayerFit(Linv, A, idx, mask.astype(outputs.dtype))


def _style_blocks(spec_factors, params, data, row_trial) -> densities.Blocks | None:
    """The style cells of a layer's training rows when its kernel is block-diagonal (every
    factor of the layer one-hot, none with learned style vectors, more than one cell); None
    otherwise (the dense path)."""
    if not spec_factors or any(STYLE_PREFIX + f in params for f in spec_factors):
        return None
    hots = [np.asarray(data.onehot[f])[row_trial] for f in spec_factors]
    if not all(np.all((h == 0) | (h == 1)) and np.all(h.sum(1) == 1) for h in hots):
        return None
    cells = densities.cell_ids(hots)
    return densities.Blocks(cells) if np.unique(cells).size > 1 else None


def condition(model, params: dict | None = None, jitter: float | None = None,
              blocked: bool = True) -> Predictor:
    """Condition every layer on the training data at ``params`` (default: the MAP).

    The work is one jitted function per model (cached on it), so conditioning on many
    posterior draws compiles once.

    ``blocked``: condition the style layers cell by cell where their kernel is block-diagonal
    (one-hot training styles; see :class:`LayerFit`); the same predictions for less work.
    False forces the dense factors (for checks).
    """
    params = {k: jnp.asarray(v) for k, v in (model.params if params is None else params).items()}
    jitter = model.diagnostics.get("jitter", 1e-8) if jitter is None else jitter
    cache = getattr(model, "_cache", None)
    name = "condition_fn" if blocked else "condition_fn_dense"
    fn = None if cache is None else cache.get(name)
    if fn is None:
        fn = jax.jit(lambda p, j: _condition(model.spec, model.data, p, j, blocked))
        if cache is not None:
            cache[name] = fn
    return fn(params, jnp.asarray(jitter, dtype=jnp.float64))


class SparseLayer(NamedTuple):
    """One factored sparse layer: its M x M parts (:class:`bayesmotion.gp.sparse.SparseParts`),
    training outputs, inducing inputs and their styles (per factor)."""

    parts: sparse.SparseParts
    outputs: jnp.ndarray
    inputs: jnp.ndarray
    styles: tuple


def _sparse_layer(terms, inputs, styles) -> SparseLayer:
    """A SparseLayer from :mod:`bayesmotion.model.layers`' sparse terms (K_uu, K_uf, diag K_ff,
    outputs, noise)."""
    Kuu, Kuf, _, outputs, noise = terms
    return SparseLayer(sparse.sparse_parts(Kuu, Kuf, outputs, noise), outputs, inputs,
                       tuple(styles))


def sparse_layers(spec, data, params, jitter) -> dict:
    """The sparse model's layers factored at ``params``: {"dynamics": SparseLayer (outputs: the
    dynamics targets less the autoregressive mean), "interaction": SparseLayer, "bottom": one
    per actor}. :func:`condition` makes its predictor from them, and the out-of-distribution
    reference (:mod:`bayesmotion.emotion.ood`) the training rows' held-out residuals."""
    h = constrained(params, spec.mapping_noise_floor)
    index = layers.DynamicsIndex(data.lengths, spec.order, data.loops)
    plan = layers.InducingPlan(int(np.sum(data.lengths)), index, spec.inducing)
    S = trial_styles(params, data)
    tof = data.trial_of_frame
    X, I = params["X"], params["I"]
    S_dyn = [S[f][tof] for f in spec.dynamics_factors]
    dyn = _sparse_layer(layers.sparse_dynamics_terms(params["Du"], I, S_dyn, plan.outs,
                                                     h["alpha"], index, jitter, ar_of(params)),
                        params["Du"], [s[index.out][plan.outs] for s in S_dyn])
    S_int = [S[f][tof] for f in spec.interaction_factors]
    inter = _sparse_layer(layers.sparse_interaction_terms(
        params["Iu"], I, jnp.concatenate(list(X), axis=1), S_int, plan.frames, h["beta"],
        jitter), params["Iu"], [s[plan.frames] for s in S_int])
    bottom = [_sparse_layer(layers.sparse_bottom_terms(params["Xu"][a], X[a],
                                                       jnp.asarray(data.Y[a]), h["gamma"],
                                                       jitter), params["Xu"][a], ())
              for a in range(X.shape[0])]
    return {"dynamics": dyn, "interaction": inter, "bottom": bottom}


def _level_vectors(spec, data, params) -> dict:
    """factor -> (K_f, K_f) style vector of every level (the identity unless learned)."""
    return {f: style_to_simplex(params[STYLE_PREFIX + f]) if STYLE_PREFIX + f in params
            else jnp.eye(data.onehot[f].shape[1]) for f in spec.factors}


def _sparse_fit(layer: SparseLayer) -> LayerFit:
    """A sparse layer's predictive in the exact one's form: weights against the inducing
    inputs and a dense (unpacked) factor."""
    W, R = sparse.predictive_weights(layer.parts)
    return LayerFit({"leaf": R}, W)


def _condition_sparse(spec, data, params, jitter) -> Predictor:
    """:func:`_condition` of the sparse model: every layer conditioned through its inducing
    inputs, which take the training inputs' place in the :class:`Predictor`."""
    L = sparse_layers(spec, data, params, jitter)
    h = constrained(params, spec.mapping_noise_floor)
    ar = ar_of(params)
    bottom = [_sparse_fit(b) for b in L["bottom"]]
    vectors = _level_vectors(spec, data, params)
    return Predictor(params["Du"], L["dynamics"].styles, _sparse_fit(L["dynamics"]), h["alpha"],
                     jnp.zeros(spec.order) if ar is None else ar, params["Iu"],
                     L["interaction"].styles, _sparse_fit(L["interaction"]), h["beta"],
                     params["Xu"], tuple(f.Linv for f in bottom), tuple(f.A for f in bottom),
                     h["gamma"], vectors)


def _condition(spec, data, params, jitter, blocked=True) -> Predictor:
    if spec.inducing is not None:
        return _condition_sparse(spec, data, params, jitter)
    h = constrained(params, spec.mapping_noise_floor)
    index = layers.DynamicsIndex(data.lengths, spec.order, data.loops)
    S = trial_styles(params, data)
    tof = data.trial_of_frame
    X, I = params["X"], params["I"]
    o = spec.order
    # dynamics
    ar = ar_of(params)
    lags, out = layers.dynamics_targets(I, index, ar)
    ar = jnp.zeros(o) if ar is None else ar
    noise_prec = kernels.dynamics_noise_precision(h["alpha"])
    dyn_style = tuple(S[f][tof][index.out] for f in spec.dynamics_factors)
    cells = _style_blocks(spec.dynamics_factors, params, data, tof[index.out]) if blocked else None
    if cells is None:
        Kd = kernels.dynamics_kernel(lags, lags, dyn_style, dyn_style, h["alpha"])
        dyn = _fit_layer(Kd + jnp.eye(out.shape[0]) / noise_prec, out, jitter)
    else:  # within a cell the style factor is exactly 1
        dyn = _fit_blocked(lambda ix: kernels.dynamics_kernel(
            [l[ix] for l in lags], [l[ix] for l in lags], [], [], h["alpha"]),
            1.0 / noise_prec, out, cells, jitter)
    # interaction
    int_style = tuple(S[f][tof] for f in spec.interaction_factors)
    Z = jnp.concatenate(list(X), axis=1)
    cells = _style_blocks(spec.interaction_factors, params, data, tof) if blocked else None
    if cells is None:
        Ki = kernels.interaction_kernel(I, I, int_style, int_style, h["beta"])
        inter = _fit_layer(Ki + jnp.eye(I.shape[0]) / h["beta"][2], Z, jitter)
    else:
        inter = _fit_blocked(lambda ix: kernels.rbf(I[ix], I[ix], h["beta"][0], h["beta"][1]),
                             1.0 / h["beta"][2], Z, cells, jitter)
    # bottom, per actor
    Ls, As = [], []
    for a in range(X.shape[0]):
        Kb = kernels.bottom_kernel(X[a], X[a], h["gamma"]) + jnp.eye(X.shape[1]) / h["gamma"][2]
        f = _fit_layer(Kb, jnp.asarray(data.Y[a]), jitter)
        Ls.append(f.Linv)
        As.append(f.A)
    vectors = _level_vectors(spec, data, params)
    return Predictor(jnp.stack(lags), dyn_style, dyn, h["alpha"], ar, I, int_style, inter,
                     h["beta"], X, tuple(Ls), tuple(As), h["gamma"], vectors)


def restrict_to_styles(P: Predictor, dyn_style_new, int_style_new) -> Predictor:
    """P without the style cells that no new input can see: the same predictions, less work.

    In a blocked layer a cell's training rows enter a prediction only through the style
    factor prod_f (s_f . s_f') of the new input against the cell's one-hot styles; where that
    is exactly 0 for every new input (a rollout at one emotion: 7 of the 8 built-in cells)
    the rows' cross-covariances are exactly 0 and add nothing to the mean or the variance.
    Dropping them is exact, not an approximation (tested against the full predictor). Dense
    layers (learned or sampled style vectors) are returned as they are.

    Args:
        dyn_style_new: per dynamics factor, (B, K_f) style vectors of the new inputs.
        int_style_new: per interaction factor, (B, K_f).
    """
    out = {}
    if P.dyn.rows is not None:
        keep, idx, rows = _kept_rows(P.dyn, _seen_cells(P.dyn, P.dyn_style, dyn_style_new))
        fit, lags, styles = _take_cells(P.dyn, keep, idx, rows, P.dyn_lags, P.dyn_style,
                                        axis=1)
        out.update(dyn=fit, dyn_lags=lags, dyn_style=styles)
    if P.inter.rows is not None:
        keep, idx, rows = _kept_rows(P.inter, _seen_cells(P.inter, P.int_style, int_style_new))
        fit, I, styles = _take_cells(P.inter, keep, idx, rows, P.I, P.int_style)
        out.update(inter=fit, I=I, int_style=styles)
    return P._replace(**out)


def _seen_cells(fit: LayerFit, train_style, new_style) -> np.ndarray:
    """Cells whose style factor is nonzero for some new input (host NumPy; exact zeros)."""
    first = np.asarray(fit.rows)[:, 0]  # a real row of each cell (padding comes last)
    w = np.ones((np.asarray(new_style[0]).shape[0] if new_style else 1, first.size))
    for s_new, s_train in zip(new_style, train_style, strict=True):
        w = w * (np.asarray(s_new) @ np.asarray(s_train)[first].T)
    keep = np.flatnonzero(np.any(w != 0.0, axis=0))
    return keep if keep.size else np.arange(1)  # all zero: one cell, contributing 0


def _kept_rows(fit: LayerFit, keep: np.ndarray):
    """(kept cells, their rows' indices in the layer, the kept layer's own rows) on the host:
    the kept cells' rows renumbered 0, 1, ... in the same (cells, B) layout."""
    rows = np.asarray(fit.rows)[keep]
    idx = rows.ravel()
    return keep, idx, np.arange(idx.size).reshape(rows.shape)


@partial(jax.jit, static_argnames=("axis",))
def _take_cells(fit: LayerFit, keep, idx, rows, inputs, styles, axis: int = 0):
    """(LayerFit of the kept cells over their own rows, ``inputs`` at those rows along
    ``axis``, each style at those rows): one compiled program per shape, not one per
    gather (a new process pays for each program it compiles)."""
    mask = fit.mask[keep]
    A = fit.A[idx] * mask.reshape(-1)[:, None]  # padding rows repeat a real row: weight 0
    return (LayerFit(fit.Linv[keep], A, rows, mask), jnp.take(inputs, idx, axis=axis),
            tuple(s[idx] for s in styles))


def _mean_var(kx, kxx, fit: LayerFit):
    """kx: (M, B) cross-covariances, kxx: (B,) prior variances -> mean (B, D), var (B,)."""
    return kx.T @ fit.A, jnp.maximum(kxx - whitened_norms(fit, kx), 0.0)


def predict_dynamics(P: Predictor, lags_new, style_new):
    """One step of the dynamics GP.

    Args:
        lags_new: (o, B, Q_I) lagged inputs I_{t-1}, ..., I_{t-o}.
        style_new: per dynamics factor, (B, K_f).
    Returns:
        mean (B, Q_I), latent-function variance (B,) (add 1/alpha_noise for a noisy step).
    """
    kxx = kernels.dynamics_diag(list(lags_new), list(style_new), P.alpha)
    mean, var = _mean_var(_dynamics_cross(P, lags_new, style_new), kxx, P.dyn)
    return mean + layers.ar_mean(lags_new, P.ar), var


def predict_dynamics_mean(P: Predictor, lags_new, style_new):
    """The mean of :func:`predict_dynamics` alone, O(M) per input (no O(M^2) variance)."""
    return (_dynamics_cross(P, lags_new, style_new).T @ P.dyn.A
            + layers.ar_mean(lags_new, P.ar))


def dynamics_mean_stepper(P: Predictor, styles):
    """(step, xs) for ``lax.scan``: step(lags (o, Q_I), x) -> the one-step predictive mean
    (Q_I,) of :func:`predict_dynamics_mean`, with what does not change along a rollout taken
    out of the loop: the training lags' squared norms and the style factor of every step
    against every training row, xs (n_steps, M) from per-step styles (n_steps, K_f).

    Per step that leaves one batched product with the training lags, one fused elementwise
    pass and one product with the weights (a rollout is sequential, so the per-step work is
    what its time is made of)."""
    U, alpha = P.dyn_lags, P.alpha  # (o, M, Q)
    o = U.shape[0]
    norms = jnp.sum(U**2, -1)  # (o, M)
    ls = alpha[1:1 + o][:, None]
    linear = kernels.has_linear_term(alpha, o)  # static: the paper's linear kernel term

    def step(lags, style_row):
        D = jnp.einsum("lmq,lq->lm", U, lags)  # i_{t-l} . u_{t-l}
        sq = jnp.maximum(norms + jnp.sum(lags**2, -1)[:, None] - 2.0 * D, 0.0)
        k = alpha[0] * jnp.exp(-0.5 * jnp.sum(ls * sq, 0))
        if linear:
            k = k + jnp.sum(alpha[1 + o:1 + 2 * o][:, None] * D, 0)
        return (style_row * k) @ P.dyn.A + P.ar @ lags

    return step, kernels.style_gram(list(styles), list(P.dyn_style))


def _dynamics_cross(P: Predictor, lags_new, style_new):
    return kernels.dynamics_kernel(list(P.dyn_lags), list(lags_new), list(P.dyn_style),
                                   list(style_new), P.alpha)


def predict_interaction(P: Predictor, I_new, style_new):
    """I_new: (B, Q_I) -> mean of [X_1 .. X_A] (B, A*Q_X), variance (B,)."""
    kx = _interaction_cross(P, I_new, style_new)
    style_diag = jnp.ones(I_new.shape[0])
    for s in style_new:
        style_diag = style_diag * jnp.sum(s * s, -1)
    return _mean_var(kx, style_diag * P.beta[0], P.inter)


def predict_interaction_mean(P: Predictor, I_new, style_new):
    """The mean of :func:`predict_interaction` alone, O(N) per input (no O(N^2) variance)."""
    return _interaction_cross(P, I_new, style_new).T @ P.inter.A


def _interaction_cross(P: Predictor, I_new, style_new):
    return kernels.interaction_kernel(P.I, I_new, list(P.int_style), list(style_new), P.beta)


def predict_bottom(P: Predictor, a: int, X_new):
    """X_new: (B, Q_X) latents of actor a -> mean Y (B, D_a), variance (B,)."""
    kx = kernels.bottom_kernel(P.X[a], X_new, P.gamma)
    fit = LayerFit(P.bottom_Linv[a], P.bottom_A[a])
    return _mean_var(kx, jnp.full(X_new.shape[0], P.gamma[0]), fit)


def predict_bottom_mean(P: Predictor, a: int, X_new):
    """The mean of :func:`predict_bottom` alone, O(N) per input (no O(N^2) variance)."""
    return kernels.bottom_kernel(P.X[a], X_new, P.gamma).T @ P.bottom_A[a]


def noise_variances(P: Predictor) -> dict[str, jnp.ndarray]:
    return {"I": 1.0 / kernels.dynamics_noise_precision(P.alpha), "X": 1.0 / P.beta[2],
            "Y": 1.0 / P.gamma[2]}


def as_numpy(tree):
    return jax.tree_util.tree_map(np.asarray, tree)
