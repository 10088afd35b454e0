"""The hierarchical GPDM of Taubert et al. (2012) as one log-posterior.

Layers (paper symbols -> code):

* bottom: ``Y_a ~ GP(X_a)`` for each actor a with one shared ``gamma`` (eq. 1-5);
* interaction: ``[X_1, X_2] ~ GP(I)`` with the multifactor style kernel (``beta``, style ``S``);
* dynamics: second-order (or first-order) GPDM on ``I`` with an RBF kernel times the style
  factors (``alpha``, eq. 9-11) around an explicit stationary autoregressive mean
  ``sum_l a_l i_{t-l}`` (``atanh_pacf``; or, with ``dynamics_linear="kernel"``, the paper's
  linear kernel term and zero mean); the chain restarts at each trial.

The joint negative log-posterior (eq. 12) is

    -log p = -sum_a log N(Y_a | 0, K_Y(X_a))          (bottom, eq. 1-3, per column)
             -log N([X_1 X_2] | 0, K_X(I, S))         (interaction)
             -w log N(I_out - sum_l a_l I_out-l | 0, K_I(I_in, S))   (dynamics, eq. 11;
                                                       w = HGPDM.dynamics_weight, 1 by default)
             -sum_trials log N(I_first | 0, init_var) (restart prior, eq. 9)
             -log p(gamma, beta, alpha) - log p(S)    (priors, see bayesmotion.model.params)

For one-actor data the interaction layer maps I to X_1 alone. In the sparse model
(``HGPDM(inducing=M)``) each layer's log N(.) is replaced by Titsias's bound with inducing
inputs ``Xu``, ``Iu``, ``Du`` (:mod:`bayesmotion.gp.sparse`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from bayesmotion.errors import BayesmotionError
from bayesmotion.gp import densities
from bayesmotion.model import layers
from bayesmotion.model.data import ModelData
from bayesmotion.model.params import (
    AR_KEY,
    STYLE_PREFIX,
    StylePrior,
    ar_coefficients,
    log_prior_hyper,
    log_prior_style,
    style_to_simplex,
)

if TYPE_CHECKING:
    from bayesmotion.model.spec import HGPDM


def trial_styles(params: dict, data: ModelData) -> dict[str, jnp.ndarray]:
    """factor -> (R, K_f) style vector of every trial: its level's free vector (params holds
    one per level, (K_f, K_f - 1) unconstrained) or, when not free, its one-hot label."""
    out = {}
    for f, h in data.onehot.items():
        key = STYLE_PREFIX + f
        h = jnp.asarray(h)
        out[f] = h @ style_to_simplex(params[key]) if key in params else h
    return out


def ar_of(params: dict):
    """The explicit autoregression's coefficients (o,), or None when the model has the paper's
    linear kernel term instead (no ``atanh_pacf`` parameter)."""
    return ar_coefficients(params[AR_KEY]) if AR_KEY in params else None


#: the entry of ``log_gamma`` and ``log_beta`` that is the layer's noise precision
NOISE_ENTRY = 2


def constrained(params: dict, mapping_noise_floor: float = 0.0) -> dict:
    """Positive hyperparameters from their logs. With ``mapping_noise_floor`` > 0 (the model's
    :attr:`~bayesmotion.model.spec.HGPDM.mapping_noise_floor`) the noise precisions of the
    bottom and interaction layers are ``1 / (exp(-l) + floor)``: their noise variance is the
    floor plus a free part, so it cannot fall below the floor at any parameter value."""
    out = {k[4:]: jnp.exp(v) for k, v in params.items() if k.startswith("log_")}
    if mapping_noise_floor:
        for k in ("gamma", "beta"):
            if k in out:
                free = params["log_" + k][NOISE_ENTRY]
                out[k] = out[k].at[NOISE_ENTRY].set(
                    1.0 / (jnp.exp(-free) + mapping_noise_floor))
    return out


LAYERS = ("bottom", "interaction", "dynamics")


class LogPosterior:
    """The joint log-posterior of eq. 12 as a pure function of the parameter dict.

    ``LogPosterior(spec, data)(params, jitter)`` -> scalar; -inf outside the support.
    With ``spec.inducing`` every layer is its sparse bound (:mod:`bayesmotion.gp.sparse`),
    with the inducing inputs ``Xu``, ``Iu``, ``Du`` in ``params``. Otherwise, while a layer's
    style vectors are the fixed one-hot labels its kernel matrix is exactly block-diagonal by
    style cell and is factorised block by block (``dense=True`` forces the dense path; tests
    check both agree).
    The instance holds only static bookkeeping (indices, data), so it is safe to close over
    inside ``jit``.
    """

    def __init__(self, spec: HGPDM, data: ModelData, dense: bool = False):
        self.spec = spec
        self.dense = dense
        self.data = data
        self.index = layers.DynamicsIndex(data.lengths, spec.order, data.loops)
        self.style_prior = StylePrior.around_labels(data.onehot, spec.priors.style_kappa)
        tof = data.trial_of_frame
        int_cells = densities.cell_ids([data.onehot[f][tof] for f in spec.interaction_factors])
        dyn_cells = densities.cell_ids([data.onehot[f][tof][self.index.out]
                                     for f in spec.dynamics_factors])
        # Block-diagonal plans, used while the layer's style vectors are the fixed one-hot labels
        self.int_blocks = densities.Blocks(int_cells) if int_cells.size else None
        self.dyn_blocks = densities.Blocks(dyn_cells) if dyn_cells.size else None
        # the sparse model's inducing points (HGPDM(inducing=M)); None: the exact model
        self.inducing = (None if spec.inducing is None else
                         layers.InducingPlan(int(data.lengths.sum()), self.index, spec.inducing))

    def _fixed(self, params, factors) -> bool:
        return all(STYLE_PREFIX + f not in params for f in factors)

    def frame_styles(self, params, factors):
        S = trial_styles(params, self.data)
        tof = self.data.trial_of_frame
        return [S[f][tof] for f in factors]

    def layer_terms(self, params: dict, jitter=0.0, which=LAYERS) -> dict[str, jnp.ndarray]:
        """Each layer's log-likelihood and the log-prior, separately.

        ``which`` names the layers to compute (the others are 0). The prior covers the
        hyperparameters and style vectors present in ``params``: with the latents fixed the
        posterior factorises into ``which=("bottom",)`` with ``log_gamma`` alone (the only
        terms gamma enters) and ``which=("interaction", "dynamics")`` with the rest.
        """
        unknown = set(which) - set(LAYERS)
        if unknown:
            raise BayesmotionError(f"unknown layers {sorted(unknown)}; expected some of "
                                   f"{LAYERS}")
        params = {k: jnp.asarray(v) for k, v in params.items()}
        h = constrained(params, self.spec.mapping_noise_floor)
        X, I = params["X"], params["I"]
        A = X.shape[0]
        terms = {k: jnp.zeros(()) for k in LAYERS}
        if "bottom" in which and self.inducing is not None:
            terms["bottom"] = sum(layers.sparse_gplvm_loglik(
                params["Xu"][a], X[a], jnp.asarray(self.data.Y[a]), h["gamma"], jitter)
                for a in range(A))
        elif "bottom" in which:
            terms["bottom"] = sum(densities.gplvm_loglik(X[a], jnp.asarray(self.data.Y[a]),
                                                      h["gamma"], jitter) for a in range(A))
        if "interaction" in which:
            Z = jnp.concatenate([X[a] for a in range(A)], axis=1)
            terms["interaction"] = self._interaction(params, I, Z, h["beta"], jitter)
        if "dynamics" in which:
            terms["dynamics"] = (self.spec.dynamics_weight
                                 * self._dynamics(params, I, h["alpha"], jitter))
        prior = (log_prior_hyper(params, self.spec.priors, self.spec.order)
                 + log_prior_style(params, self.style_prior))
        return {**terms, "prior": prior}

    def _interaction(self, params, I, Z, beta, jitter):
        fi = self.spec.interaction_factors
        if self.inducing is not None:
            return layers.sparse_style_gplvm_loglik(params["Iu"], I, Z,
                                                    self.frame_styles(params, fi),
                                                    self.inducing.frames, beta, jitter)
        if self.dense or self.int_blocks is None or not self._fixed(params, fi):
            return layers.style_gplvm_loglik(I, Z, self.frame_styles(params, fi), beta, jitter)
        return layers.blocked_style_gplvm_loglik(I, Z, beta, self.int_blocks, jitter)

    def _dynamics(self, params, I, alpha, jitter):
        fd, v0 = self.spec.dynamics_factors, self.spec.priors.init_var
        ar = ar_of(params)
        if self.inducing is not None:
            return layers.sparse_gpdm_loglik(params["Du"], I, self.frame_styles(params, fd),
                                             self.inducing.outs, alpha, self.index, jitter,
                                             v0, ar)
        if self.dense or self.dyn_blocks is None or not self._fixed(params, fd):
            return layers.gpdm_loglik(I, self.frame_styles(params, fd), alpha, self.index,
                                      jitter, v0, ar)
        return layers.blocked_gpdm_loglik(I, alpha, self.index, self.dyn_blocks, jitter, v0,
                                          ar)

    def __call__(self, params: dict, jitter=0.0, which=LAYERS) -> jnp.ndarray:
        t = self.layer_terms(params, jitter, which)
        total = t["bottom"] + t["interaction"] + t["dynamics"] + t["prior"]
        return jnp.where(jnp.isnan(total), -jnp.inf, total)


def make_value_and_grad(fn):
    """Jitted value-and-gradient of a function of (flat vector, jitter)."""
    return jax.jit(jax.value_and_grad(fn))
