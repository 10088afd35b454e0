"""Per-coordinate sinh-arcsinh maps (Jones & Pewsey 2009) that turn skewed or heavy-tailed
marginals into nearly Gaussian ones (see :class:`SinhArcsinh`): an independence proposal that is
Gaussian in the mapped coordinates reaches into the tails a Gaussian in the sampled ones misses.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

# bounds of the fitted skew epsilon and log tail weight log delta: delta in [1/4, 4] spans tails
# from much heavier than a Gaussian's (delta < 1) to much lighter
SKEW_BOUND = 5.0
LOG_TAIL_BOUND = float(np.log(4.0))


def sas_forward(params, x):
    """Pure JAX: (d, 4) parameters (location, log scale, skew epsilon, log tail weight delta)
    and (n, d) values -> ((n, d) mapped values ``sinh(delta asinh((x - loc) / scale) -
    epsilon)``, (n,) log |dy/dx| summed over the coordinates)."""
    loc, log_scale, skew, log_tail = (params[:, i] for i in range(4))
    z = (x - loc) * jnp.exp(-log_scale)
    a = jnp.exp(log_tail) * jnp.arcsinh(z) - skew
    # log cosh a, stable for large |a|
    log_cosh = jnp.abs(a) + jnp.log1p(jnp.exp(-2.0 * jnp.abs(a))) - jnp.log(2.0)
    log_jac = log_tail - log_scale + log_cosh - jnp.log(jnp.hypot(1.0, z))  # no z * z overflow
    return jnp.sinh(a), jnp.sum(log_jac, -1)


def sas_log_density(params, x):
    """Pure JAX: (n,) log-density of (n, d) values under independent sinh-arcsinh marginals,
    each the law of ``loc + scale sinh((asinh(u) + epsilon) / delta)`` with ``u ~ N(0, 1)``."""
    y, log_jac = sas_forward(params, x)
    d = x.shape[-1]
    return log_jac - 0.5 * jnp.sum(y * y, -1) - 0.5 * d * jnp.log(2.0 * jnp.pi)


_forward_jit = jax.jit(sas_forward)  # one program per block shape, called twice per step


@jax.jit
def _mean_nll_and_grad(flat, x):
    def nll(p):
        return -jnp.mean(sas_log_density(p.reshape(-1, 4), x))

    return jax.value_and_grad(nll)(flat)


class SinhArcsinh:
    """A monotone map ``y = sinh(delta asinh((x - loc) / scale) - epsilon)`` of each of d
    coordinates: a Gaussian ``y`` makes ``x`` sinh-arcsinh distributed, skewed by ``epsilon`` and
    with tails heavier (``delta < 1``) or lighter (``delta > 1``) than a Gaussian's; ``epsilon
    = 0, delta = 1`` is the affine map ``(x - loc) / scale``.

    Args:
        params: (d, 4) per coordinate: location, log scale, epsilon, log delta.

    :meth:`fit` estimates them by maximum likelihood from samples.
    """

    def __init__(self, params):
        params = np.asarray(params, dtype=np.float64)
        if params.ndim != 2 or params.shape[1] != 4 or not np.all(np.isfinite(params)):
            raise ValueError(f"params must be a finite (d, 4) array, got shape {params.shape}")
        self.params = params

    @property
    def ndim(self) -> int:
        return self.params.shape[0]

    @classmethod
    def fit(cls, z) -> SinhArcsinh:
        """Maximum-likelihood marginals of the rows of ``z`` (n, d), each coordinate its own
        sinh-arcsinh law (L-BFGS-B; skew and log tail weight bounded by ``SKEW_BOUND`` and
        ``LOG_TAIL_BOUND``). A coordinate whose values do not vary, or whose fit does not end
        finite, gets the affine map of its mean and standard deviation (or the identity)."""
        z = np.asarray(z, dtype=np.float64)
        if z.ndim != 2 or len(z) < 2:
            raise ValueError(f"fit needs (n >= 2, d) samples, got shape {z.shape}")
        d = z.shape[1]
        med, sd = np.median(z, 0), z.std(0)
        ok = np.isfinite(sd) & (sd > 0) & np.all(np.isfinite(z), 0)
        start = np.zeros((d, 4))
        start[:, 0] = np.where(ok, med, 0.0)
        start[:, 1] = np.log(np.where(ok, sd, 1.0))
        params = start.copy()
        if ok.any():
            zo = jnp.asarray(z[:, ok])
            s0 = start[ok]
            bounds = [b for row in s0 for b in (
                (None, None), (row[1] - 10.0, row[1] + 10.0),
                (-SKEW_BOUND, SKEW_BOUND), (-LOG_TAIL_BOUND, LOG_TAIL_BOUND))]

            def fun(flat):
                v, g = _mean_nll_and_grad(jnp.asarray(flat), zo)
                return float(v), np.asarray(g, dtype=np.float64)

            res = minimize(fun, s0.ravel(), jac=True, method="L-BFGS-B", bounds=bounds,
                           options={"maxiter": 500})
            fitted = res.x.reshape(-1, 4)
            good = np.all(np.isfinite(fitted), 1)
            affine = s0.copy()
            affine[:, 0] = z[:, ok].mean(0)
            params[ok] = np.where(good[:, None], fitted, affine)
        return cls(params)

    def forward(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(n, d) -> ((n, d) mapped values, (n,) log |dy/dx|)."""
        y, log_jac = _forward_jit(jnp.asarray(self.params), jnp.asarray(x, dtype=jnp.float64))
        return np.asarray(y, dtype=np.float64), np.asarray(log_jac, dtype=np.float64)

    def inverse(self, y) -> np.ndarray:
        """(n, d) mapped values -> (n, d) values (inf where they overflow)."""
        y = np.asarray(y, dtype=np.float64)
        loc, log_scale, skew, log_tail = self.params.T
        with np.errstate(over="ignore", invalid="ignore"):
            return loc + np.exp(log_scale) * np.sinh((np.arcsinh(y) + skew) * np.exp(-log_tail))

    def slope(self, x) -> np.ndarray:
        """(n, d) values -> (n, d) dy/dx of each coordinate."""
        x = np.asarray(x, dtype=np.float64)
        loc, log_scale, skew, log_tail = self.params.T
        z = (x - loc) * np.exp(-log_scale)
        a = np.exp(log_tail) * np.arcsinh(z) - skew
        with np.errstate(over="ignore"):
            return np.exp(log_tail - log_scale) * np.cosh(a) / np.hypot(1.0, z)
