"""The H-GPDM's layers as log-likelihoods: the interaction GP-LVM with the multifactor style
kernel and the GPDM of order 1 or 2 over many trials (eq. 9, 11), dense and block-diagonal.

The Gaussian log-densities they call, and their numerics, are in :mod:`bayesmotion.gp.densities`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from bayesmotion.gp import kernels, sparse
from bayesmotion.gp.densities import LOG_2PI, Blocks, blocked_gaussian_loglik, gaussian_loglik


def restart_log_prior(first, init_var):
    """sum of log N(i | 0, init_var I) over the first o frames of every trial (eq. 9): the
    dynamics chain restarts at each trial from this isotropic prior."""
    return -0.5 * jnp.sum(first**2) / init_var - 0.5 * first.size * (LOG_2PI + jnp.log(init_var))


def ar_mean(lags, a):
    """sum_l a_l lags[l]: the explicit linear part of the dynamics' mean. lags: o arrays
    (..., Q) (I_{t-1} first), a: (o,)."""
    return sum(a[l] * lags[l] for l in range(len(lags)))


def style_gplvm_loglik(I, Z, S, beta, jitter=0.0):
    """Interaction layer: log p(Z | I, beta, S) with the multifactor kernel.

    K_X = (c c'^T)(e e'^T) o beta1 exp(-beta2/2 |i-i'|^2) + beta3^-1 I.
    I: (N, Q_I), Z: (N, D_Z) stacked actor latents [X1, X2], S: per-factor (N, K_f).
    """
    K = kernels.interaction_kernel(I, I, S, S, beta) + jnp.eye(I.shape[0]) / beta[2]
    return gaussian_loglik(K, Z, jitter)


def dynamics_io(I: jnp.ndarray, index: DynamicsIndex):
    """Inputs (o lags) and outputs of the dynamics GP, gathered by precomputed indices."""
    lags = [I[index.lag[l]] for l in range(index.order)]
    return lags, I[index.out]


class DynamicsIndex:
    """Frame indices of a multi-trial GPDM of order o; static (NumPy) bookkeeping.

    For every trial with frames [s, e), the outputs are frames s+o .. e-1 and lag l (1..o) of
    output t is frame t-l: the Markov chain restarts at each trial, whose first o frames get the
    isotropic Gaussian prior instead (eq. 9 / 11).

    ``loops`` (periodic models, :func:`bayesmotion.model.data.find_loops`): per trial, -1 or
    the trial-local frame k whose o frames match the trial's last o: the frame after the last
    then continues as frame k + o did. o rows are added per such trial, read along the wrapped
    sequence e-o, .., e-1, s+k+o, .., s+k+2o-1: outputs s+k+o+m (m < o) with lag l the frame
    l before it in that sequence. ``n_loop_rows`` counts them.
    """

    def __init__(self, lengths, order: int, loops=None):
        if order not in (1, 2):
            raise ValueError(f"dynamics order must be 1 or 2, got {order}")
        lengths = [int(n) for n in lengths]
        if min(lengths) <= order:
            raise ValueError(f"every trial needs more than {order} frames; got {min(lengths)}")
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        self.order = order
        self.lengths = np.asarray(lengths)
        self.starts = starts
        self.out = np.concatenate([np.arange(s + order, s + n)
                                   for s, n in zip(starts, lengths, strict=True)])
        self.lag = [self.out - l for l in range(1, order + 1)]
        self.first = np.concatenate([np.arange(s, s + order) for s in starts])
        self.trial_of_frame = np.repeat(np.arange(len(lengths)), lengths)
        self.n_loop_rows = 0
        if loops is None:
            return
        loops = np.asarray(loops)
        if loops.shape != (len(lengths),):
            raise ValueError(f"loops must hold one frame per trial, got shape {loops.shape}")
        out, lag = [], [[] for _ in range(order)]
        for s, n, k in zip(starts, lengths, loops, strict=True):
            if k < 0:
                continue
            if k + 2 * order > n:
                raise ValueError(f"loop frame {k} leaves no {order} frames to continue with in a "
                                 f"trial of {n}")
            seq = [s + n - order + j for j in range(order)] + [s + k + order + j
                                                                for j in range(order)]
            for m in range(order):
                out.append(seq[order + m])
                for l in range(1, order + 1):
                    lag[l - 1].append(seq[order + m - l])
        self.n_loop_rows = len(out)
        self.out = np.concatenate([self.out, np.asarray(out, int)])
        self.lag = [np.concatenate([a, np.asarray(b, int)]) for a, b in zip(self.lag, lag,
                                                                          strict=True)]


def evenly_spaced(n: int, m: int) -> np.ndarray:
    """min(m, n) distinct indices spread evenly over range(n), first and last included."""
    m = min(int(m), int(n))
    return np.round(np.linspace(0, n - 1, m)).astype(int) if m > 1 else np.zeros(1, int)


class InducingPlan:
    """Which training rows give the sparse model's inducing points their style (static).

    Inducing point m of the bottom and interaction layers starts at training frame
    ``frames[m]`` and keeps that frame's style for good (its inputs move, its style follows
    the frame's trial, learned vectors included); those of the dynamics layer likewise with
    the dynamics' output rows ``outs``. Evenly spaced, so every trial and style cell gets a
    share in proportion to its frames.
    """

    def __init__(self, n_frames: int, index: DynamicsIndex, m: int):
        self.frames = evenly_spaced(n_frames, m)
        self.outs = evenly_spaced(index.out.size, m)


def dynamics_targets(I, index: DynamicsIndex, ar=None):
    """(lags, outputs) of the dynamics GP: the outputs less the explicit autoregressive mean
    sum_l a_l i_{t-l} when ``ar`` (o,) is given (the GP then models what the stable linear
    part does not explain)."""
    lags, out = dynamics_io(I, index)
    return lags, (out if ar is None else out - ar_mean(lags, ar))


def gpdm_loglik(I, S, alpha, index: DynamicsIndex, jitter=0.0, prior_var=1.0, ar=None):
    """Dynamics layer: log p(I | alpha, S) for a GPDM of order 1 or 2 over many trials.

    log p = log N(I_out - sum_l a_l I_{out-l} | 0, K_I) (columns independent, eq. 11)
            + sum over each trial's first o frames of log N(i | 0, prior_var * I).

    I: (N, Q) latents of all trials stacked; S: per-factor (N, K_f) per-frame style; ar: (o,)
    coefficients of the explicit stable linear mean, or None (the paper's zero mean, with the
    linear part in the kernel).
    """
    lags, out = dynamics_targets(I, index, ar)
    S_out = [s[index.out] for s in S]
    K = kernels.dynamics_kernel(lags, lags, S_out, S_out, alpha)
    K = K + jnp.eye(out.shape[0]) / kernels.dynamics_noise_precision(alpha)
    ll = gaussian_loglik(K, out, jitter)
    return ll + restart_log_prior(I[index.first], prior_var)


def _noise(kdiag, noise_var, jitter):
    """The noise variance plus the dense path's jitter, jitter * mean(diag(K + noise I))."""
    return noise_var + jitter * (jnp.mean(kdiag) + noise_var)


# Each sparse layer as the arguments of bayesmotion.gp.sparse (K_uu, K_uf, diag K_ff, outputs,
# noise variance with the jitter): the log-likelihoods below and the conditioned predictor
# (bayesmotion.model.predict) build them here, once.
def sparse_bottom_terms(U, X, Y, gamma, jitter=0.0):
    """Bottom layer with inducing inputs U (M, Q_X)."""
    kdiag = jnp.full(X.shape[0], gamma[0])
    return (kernels.bottom_kernel(U, U, gamma), kernels.bottom_kernel(U, X, gamma), kdiag, Y,
            _noise(kdiag, 1.0 / gamma[2], jitter))


def sparse_interaction_terms(U, I, Z, S, rows, beta, jitter=0.0):
    """Interaction layer with inducing inputs U (M, Q_I), whose styles are those of the
    training frames ``rows`` (:class:`InducingPlan`); S per-frame styles (per factor)."""
    S_u = [s[rows] for s in S]
    kdiag = beta[0] * kernels.style_gram_diag(S, I.shape[0])
    return (kernels.interaction_kernel(U, U, S_u, S_u, beta),
            kernels.interaction_kernel(U, I, S_u, S, beta), kdiag, Z,
            _noise(kdiag, 1.0 / beta[2], jitter))


def sparse_dynamics_terms(U, I, S, rows, alpha, index: DynamicsIndex, jitter=0.0, ar=None):
    """Dynamics layer with inducing lag inputs U (o, M, Q_I), whose styles are those of the
    output rows ``rows``; S per-frame styles (as :func:`gpdm_loglik`)."""
    lags, out = dynamics_targets(I, index, ar)
    S_out = [s[index.out] for s in S]
    S_u = [s[rows] for s in S_out]
    kdiag = kernels.dynamics_diag(lags, S_out, alpha)
    return (kernels.dynamics_kernel(list(U), list(U), S_u, S_u, alpha),
            kernels.dynamics_kernel(list(U), lags, S_u, S_out, alpha), kdiag, out,
            _noise(kdiag, 1.0 / kernels.dynamics_noise_precision(alpha), jitter))


def sparse_gplvm_loglik(U, X, Y, gamma, jitter=0.0):
    """Bottom layer, sparse: Titsias's bound of log p(Y | X, gamma) with inducing inputs U."""
    return sparse.sparse_loglik(*sparse_bottom_terms(U, X, Y, gamma, jitter))


def sparse_style_gplvm_loglik(U, I, Z, S, rows, beta, jitter=0.0):
    """Interaction layer, sparse (:func:`sparse_interaction_terms`)."""
    return sparse.sparse_loglik(*sparse_interaction_terms(U, I, Z, S, rows, beta, jitter))


def sparse_gpdm_loglik(U, I, S, rows, alpha, index: DynamicsIndex, jitter=0.0, prior_var=1.0,
                       ar=None):
    """Dynamics layer, sparse (:func:`sparse_dynamics_terms`), with the restart prior."""
    ll = sparse.sparse_loglik(*sparse_dynamics_terms(U, I, S, rows, alpha, index, jitter, ar))
    return ll + restart_log_prior(I[index.first], prior_var)


def blocked_style_gplvm_loglik(I, Z, beta, blocks: Blocks, jitter=0.0):
    """Interaction layer for one-hot styles: within a cell the style factor is exactly 1."""
    return blocked_gaussian_loglik(lambda ix: kernels.rbf(I[ix], I[ix], beta[0], beta[1]),
                                   Z, 1.0 / beta[2], blocks, jitter)


def blocked_gpdm_loglik(I, alpha, index: DynamicsIndex, blocks: Blocks, jitter=0.0,
                        prior_var=1.0, ar=None):
    """Dynamics layer for one-hot styles (blocks group the *output* rows by style cell)."""
    lags, out = dynamics_targets(I, index, ar)
    ones = jnp.ones((out.shape[0], 1))

    def K_rows(ix):
        la = [l[ix] for l in lags]
        return kernels.dynamics_kernel(la, la, [ones[ix]], [ones[ix]], alpha)

    ll = blocked_gaussian_loglik(K_rows, out, 1.0 / kernels.dynamics_noise_precision(alpha),
                                 blocks, jitter)
    return ll + restart_log_prior(I[index.first], prior_var)
