"""Parameter pytrees: unconstrained storage, the transform table, and priors.

Parameters are a flat ``dict[str, array]`` (a pytree), stored unconstrained:

============  ==================  ========================  =====================================
key           shape               constrained value         prior (numpyro.distributions)
============  ==================  ========================  =====================================
X             (A, N, Q_X)         identity                  hierarchy: p([X1 X2] | I, beta, S)
I             (N, Q_I)            identity                  hierarchy: p(I | alpha, S), eq. 9/11
log_gamma     (3,)                gamma = exp(.)            Normal(loc, scale) on log gamma
log_beta      (3,)                beta = exp(.)             Normal(loc, scale) on log beta
log_alpha     (2 + o,)            alpha = exp(.)            Normal(loc, scale) on log alpha
              (2 + 2 o,) with the paper's linear kernel term (``dynamics_linear="kernel"``)
atanh_pacf    (o,)                AR coefficients           partial autocorrelations tanh(.)
                                  (:func:`ar_coefficients`) each Uniform(-1, 1)
                                  (only with ``dynamics_linear="stable"``, the default)
style:<f>     (K_f, K_f - 1)      simplex (stick-breaking)  Dirichlet(1 + kappa * onehot(level))
Xu            (A, M, Q_X)         identity                  none: variational parameters
Iu            (M, Q_I)            identity                  none: variational parameters
Du            (o, M', Q_I)        identity                  none: variational parameters
============  ==================  ========================  =====================================

With ``HGPDM(mapping_noise_floor=v)`` the noise entry (index 2) of gamma and beta is
``1 / (exp(-l) + v)`` instead of ``exp(l)`` (:func:`bayesmotion.model.logpost.constrained`); the
prior stays on ``l``, the free part.

``Xu``, ``Iu`` and ``Du`` exist only in the sparse model (``HGPDM(inducing=M)``): the inducing
inputs of the bottom layer (per actor), of the interaction layer and of the dynamics layer (its
o lags; M' = min(M, number of dynamics outputs)). They are parameters of the variational bound,
not of the model, so they have no prior; they are fitted with the latents and held fixed with
them by the samplers.

Log-densities are evaluated in the unconstrained space and include the log-det-Jacobian of
every transform (as numpyro's ``potential_energy`` does). A Normal prior on ``log theta`` *is* the
density of ``log theta``, so that Jacobian is implicit; the stick-breaking Jacobian is added
explicitly. MAP therefore maximises the same function the samplers explore, and a style vector's
MAP lies inside the simplex rather than on a vertex.

Why log-normal priors instead of the paper's scale-free ``p(theta) ~ 1/theta``: the scale-free
prior is improper, so the posterior need not be proper and MCMC over hyperparameters would be
ill-defined; a Normal on ``log theta`` with a large scale (3 by default, i.e. a factor of ~20 per
standard deviation) is flat over the range the data can inform and proper everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
import numpyro.distributions as dist
from jax.scipy.special import gammaln
from numpyro.distributions.transforms import StickBreakingTransform

from bayesmotion.errors import BayesmotionError

STYLE_PREFIX = "style:"
_STICK = StickBreakingTransform()


@dataclass(frozen=True)
class Priors:
    """Prior settings (all proper).

    Attributes:
        log_scale: standard deviation of the Normal prior of every log-hyperparameter.
        gamma_loc, beta_loc: prior medians (log space is centred on log of these) of
            (signal variance, inverse squared lengthscale, noise precision).
        alpha_rbf, alpha_ls, alpha_lin, alpha_noise: prior medians of the dynamics kernel's
            parameters (the ls/lin medians apply to every lag; alpha_lin only with the
            paper's linear kernel term, ``HGPDM(dynamics_linear="kernel")``).
        style_kappa: Dirichlet concentration of each level's style vector around its own
            vertex: the vector of level k has prior Dirichlet(1 + kappa * onehot(k)).
        init_var: variance of the isotropic Gaussian prior of each trial's first o frames of I.
    """

    log_scale: float = 3.0
    gamma_loc: tuple[float, float, float] = (1.0, 1.0, 100.0)
    beta_loc: tuple[float, float, float] = (1.0, 1.0, 100.0)
    alpha_rbf: float = 1.0
    alpha_ls: float = 1.0
    alpha_lin: float = 1.0
    alpha_noise: float = 100.0
    style_kappa: float = 10.0
    init_var: float = 1.0

    def __post_init__(self):
        def positive(name, v, n=None):
            a = np.asarray(v, dtype=np.float64) if _numeric(v) else None
            if a is None or (n is not None and a.shape != (n,)) or (n is None and a.ndim) \
                    or not np.all(np.isfinite(a)) or np.any(a <= 0):
                what = f"{n} positive numbers" if n else "a positive number"
                raise BayesmotionError(f"Priors.{name} must be {what}, got {v!r}")

        positive("log_scale", self.log_scale)
        positive("gamma_loc", self.gamma_loc, 3)
        positive("beta_loc", self.beta_loc, 3)
        for name in ("alpha_rbf", "alpha_ls", "alpha_lin", "alpha_noise", "init_var"):
            positive(name, getattr(self, name))
        k = np.asarray(self.style_kappa, dtype=np.float64) if _numeric(self.style_kappa) \
            else None
        if k is None or k.ndim or not np.isfinite(k) or k < 0:
            raise BayesmotionError(f"Priors.style_kappa must be a number >= 0, got "
                                   f"{self.style_kappa!r}")

    def alpha_loc(self, order: int, linear: bool = True) -> np.ndarray:
        """Prior medians of alpha, with the linear kernel's weights (``linear``) or without."""
        lin = [self.alpha_lin] * order if linear else []
        return np.array([self.alpha_rbf] + [self.alpha_ls] * order + lin + [self.alpha_noise])

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> Priors:
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})


def _numeric(v) -> bool:
    try:
        np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return not isinstance(v, str | bytes | bool)


def hyper_prior_locs(priors: Priors, order: int, linear: bool = True) -> dict[str, np.ndarray]:
    return {"log_gamma": np.log(priors.gamma_loc), "log_beta": np.log(priors.beta_loc),
            "log_alpha": np.log(priors.alpha_loc(order, linear))}


def ar_coefficients(u):
    """Unconstrained (o,) -> the coefficients (a_1, .., a_o) of a stationary autoregression
    i_t = sum_l a_l i_{t-l}.

    Through the partial autocorrelations phi = tanh(u) in (-1, 1) (Barndorff-Nielsen and
    Schou 1973; Monahan 1984): order 1, a_1 = phi_1; order 2, a_1 = phi_1 (1 - phi_2),
    a_2 = phi_2. This maps R^o onto exactly the stationary region (every root of
    1 - sum_l a_l z^l outside the unit circle; for order 2 the triangle |a_2| < 1,
    a_2 +- a_1 < 1), so an explosive linear part cannot be represented at any parameter value.
    """
    phi = jnp.tanh(jnp.asarray(u))
    if phi.shape[0] == 1:
        return phi
    if phi.shape[0] == 2:
        return jnp.stack([phi[0] * (1.0 - phi[1]), phi[1]])
    raise ValueError(f"autoregression order must be 1 or 2, got {phi.shape[0]}")


def ar_pacf(a) -> np.ndarray:
    """Inverse of :func:`ar_coefficients` on the partial autocorrelations: (a_1, .., a_o) ->
    phi. Raises ValueError outside the stationary region."""
    a = np.asarray(a, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = a.copy() if a.size == 1 else np.array([a[0] / (1.0 - a[1]), a[1]])
    if not np.all(np.abs(phi) < 1.0):
        raise ValueError(f"autoregression coefficients {a.tolist()} are not stationary")
    return phi


def ar_log_prior(u):
    """log density of u when every partial autocorrelation tanh(u_l) is Uniform(-1, 1), i.e.
    uniform over the stationary region in partial-autocorrelation coordinates (Jones 1987):
    sum_l log(1 - tanh(u_l)^2) - o log 2, written stably."""
    u = jnp.asarray(u)
    return jnp.sum(2.0 * (jnp.log(2.0) - jnp.abs(u) - jnp.log1p(jnp.exp(-2.0 * jnp.abs(u))))
                   - jnp.log(2.0))


def style_to_simplex(u: jnp.ndarray) -> jnp.ndarray:
    """(R, K-1) unconstrained -> (R, K) on the simplex (numpyro stick-breaking)."""
    return _STICK(u)


def simplex_to_style(s) -> jnp.ndarray:
    """(R, K) on the simplex (strictly inside) -> (R, K-1) unconstrained."""
    return _STICK.inv(jnp.asarray(s))


def style_log_jacobian(u: jnp.ndarray) -> jnp.ndarray:
    """Sum over trials of log |det d simplex / d u| of the stick-breaking transform."""
    return jnp.sum(_STICK.log_abs_det_jacobian(u, _STICK(u)))


@dataclass(frozen=True)
class StylePrior:
    """Dirichlet prior of each level's style vector around its own vertex.

    As in Wang et al.'s multifactor model there is one style vector per level of a factor
    (every trial labelled "happy" shares the happy vector); free vectors live on the simplex.
    """

    concentration: dict[str, np.ndarray] = field(default_factory=dict)  # factor -> (K, K)

    @classmethod
    def around_labels(cls, onehots: dict[str, np.ndarray], kappa: float) -> StylePrior:
        return cls({f: 1.0 + kappa * np.eye(np.asarray(h).shape[1])
                    for f, h in onehots.items()})


AR_KEY = "atanh_pacf"
#: the sparse model's inducing inputs (bottom, interaction, dynamics)
INDUCING_KEYS = ("Xu", "Iu", "Du")
#: what the samplers hold fixed at the MAP: the latents and, in a sparse model, its inducing inputs
LATENT_KEYS = ("X", "I", *INDUCING_KEYS)


def log_prior_hyper(params: dict, priors: Priors, order: int) -> jnp.ndarray:
    """sum of Normal(log theta | log median, log_scale) over gamma, beta, alpha, and the
    autoregression's uniform partial-autocorrelation prior (:func:`ar_log_prior`) when the
    dynamics has an explicit stable linear part."""
    linear = AR_KEY not in params
    locs = hyper_prior_locs(priors, order, linear)
    lp = 0.0
    for key, loc in locs.items():
        if key in params:
            lp = lp + jnp.sum(dist.Normal(loc, priors.log_scale).log_prob(params[key]))
    if not linear:
        lp = lp + ar_log_prior(params[AR_KEY])
    return lp


def log_dirichlet(s, conc) -> jnp.ndarray:
    """log Dirichlet(s | conc) over the last axis, (..., K) -> (...): the one style prior.

    ``s`` is clipped away from exact zeros (float underflow at extreme stick coordinates) so
    the density stays finite."""
    s = jnp.clip(jnp.asarray(s), 1e-300, 1.0)
    conc = jnp.asarray(conc)
    return (jnp.sum((conc - 1.0) * jnp.log(s), -1) + gammaln(jnp.sum(conc, -1))
            - jnp.sum(gammaln(conc), -1))


def style_log_prior(params: dict, concentration: dict) -> jnp.ndarray:
    """Dirichlet log-density of every free style vector in ``params`` (keys
    ``STYLE_PREFIX + factor``, unconstrained ``(..., K - 1)``) plus the stick-breaking
    log-Jacobian; ``concentration[factor]`` broadcasts against the vectors' simplex points."""
    lp = 0.0
    for key, u in params.items():
        if key.startswith(STYLE_PREFIX):
            conc = concentration[key[len(STYLE_PREFIX):]]
            lp = lp + jnp.sum(log_dirichlet(style_to_simplex(u), conc)) + style_log_jacobian(u)
    return lp


def log_prior_style(params: dict, style_prior: StylePrior) -> jnp.ndarray:
    """Dirichlet log-density of free style vectors plus the stick-breaking log-Jacobian."""
    return style_log_prior(params, style_prior.concentration)
