"""Differential evolution in coordinates where the kernels' output scales do not trade off
against the style vectors' norms.

The interaction and dynamics kernels multiply their output scale (``beta1``, ``alpha1``, and
the linear weights when the dynamics has the linear kernel term) by the style factor
``prod_f s_f^T s_f'`` (:func:`bayesmotion.gp.kernels.style_gram`). What the latents pin is their
product: the prior variance a training frame gets, ``beta1 prod_f |s_f|^2``. Moving every style
vector towards the simplex's centre shrinks ``|s_f|^2``, and the likelihood stays put if the
output scales grow by as much: a curved ridge in the sampled coordinates (the log scales
against the stick-breaking coordinates), along which differential evolution, whose proposals
are straight lines, crawls.

:class:`StyleShear` is the map ``y = phi(x)`` that adds ``log g(S)`` to each of those log
scales, with

    g(S) = sum_n w_n prod_f |s_f(n)|^2,

the frame-weighted mean (``w_n``: frames of trial n / all frames) of the style part of the
kernels' diagonal, ``s_f(n)`` the style vector of trial n's level of factor f. The style
coordinates pass through unchanged, so ``phi`` is a shear: its Jacobian is triangular with a unit
diagonal, ``|det dphi/dx| = 1``. In ``y`` the log scales are those of the mean prior variance
itself, and the ridge is (nearly) straight.

:class:`ShearedDE` is emcee's :class:`~emcee.moves.DEMove` proposing in ``y``: it maps the
walkers (and the complementary ensemble) to ``y``, takes emcee's differential-evolution step
there, and maps the proposals back. A proposal symmetric in ``y`` under a volume-preserving
bijection is symmetric in ``x``, so the acceptance is the plain density ratio (DE's own zero
log-factor) and the chain, its files and its diagnostics stay in the model's coordinates. The
move costs one log-density per walker, as DE does. Measured in
``benchmarks/results/style_shear.json``.
"""

from __future__ import annotations

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.gp.kernels import has_linear_term
from bayesmotion.model.params import style_to_simplex


class StyleShear:
    """The volume-preserving map ``phi`` of the module docstring, on flat vectors.

    Args:
        style_index: factor -> flat indices ``(K * (K - 1),)`` of its unconstrained style
            block, in C order (:func:`bayesmotion.inference.moves.style_slices`).
        onehot: factor -> ``(R, K)`` one-hot level of each training trial.
        lengths: ``(R,)`` frames per trial (the weights ``w``).
        scale_index: flat indices of the log output scales that multiply the style factor.

    ``forward(xs)`` maps ``(n, d)`` walkers to ``y`` and ``inverse(ys)`` back (both jitted,
    vmapped over walkers); ``log_g(x)`` is ``log g`` at one flat vector.
    """

    def __init__(self, style_index: dict, onehot: dict, lengths, scale_index):
        lengths = np.asarray(lengths, dtype=float).ravel()
        if not style_index:
            raise ValueError("StyleShear needs at least one sampled style factor")
        if lengths.size == 0 or np.any(lengths <= 0):
            raise ValueError(f"lengths must be positive frame counts, got {lengths!r}")
        self._blocks = []
        for f, idx in style_index.items():
            oh = np.asarray(onehot[f], dtype=float)
            K = oh.shape[1]
            idx = np.asarray(idx, dtype=int).ravel()
            if oh.shape[0] != lengths.size or idx.size != K * (K - 1):
                raise ValueError(f"factor {f!r}: {oh.shape[0]} trials and {idx.size} style "
                                 f"coordinates do not fit {lengths.size} trials of {K} levels")
            self._blocks.append((jnp.asarray(idx), K, jnp.asarray(oh)))
        self.scale_index = np.asarray(scale_index, dtype=int).ravel()
        if self.scale_index.size == 0:
            raise ValueError("StyleShear needs at least one output-scale coordinate")
        self._w = jnp.asarray(lengths / lengths.sum())
        scale = jnp.asarray(self.scale_index)

        def forward(x):
            return x.at[scale].add(self.log_g(x))

        def inverse(y):  # log g reads only the style coordinates, which phi leaves alone
            return y.at[scale].add(-self.log_g(y))

        self.forward = jax.jit(jax.vmap(forward))
        self.inverse = jax.jit(jax.vmap(inverse))

    def log_g(self, x):
        """``log sum_n w_n prod_f |s_f(n)|^2`` at the flat vector ``x``."""
        d = 1.0
        for idx, K, oh in self._blocks:
            s = oh @ style_to_simplex(x[idx].reshape(K, K - 1))
            d = d * jnp.sum(s * s, -1)
        return jnp.log(jnp.sum(self._w * d))

    @classmethod
    def for_target(cls, target) -> StyleShear | None:
        """The shear of a :class:`bayesmotion.inference.target.Target` that samples style
        vectors together with the output scales they multiply; None for any other target
        (no style vectors, styles held fixed, or a bare density). Built once per target (its
        maps compile once per run, however many times the moves are rebuilt)."""
        if "_style_shear" not in vars(target):
            target._style_shear = cls._build(target)
        return target._style_shear

    @classmethod
    def _build(cls, target) -> StyleShear | None:
        from bayesmotion.inference.moves.rotations import style_slices

        model = getattr(target, "model", None)
        names = getattr(target, "names", None)
        data = getattr(model, "data", None)
        if (names is None or not hasattr(target, "unravel") or data is None
                or not hasattr(model, "params") or not hasattr(model, "spec")):
            return None  # a bare density, or a stand-in without the model's trials
        slices = style_slices(target.unravel, target.x0)
        if not slices:
            return None
        scales = [n for n in ("log_beta[0]", "log_alpha[0]") if n in names]
        alpha = model.params.get("log_alpha")
        if "log_alpha[0]" in names and alpha is not None and has_linear_term(
                np.asarray(alpha), model.spec.order):
            o = model.spec.order
            scales += [f"log_alpha[{1 + o + l}]" for l in range(o)]
        if not scales:
            return None
        return cls(slices, {f: data.onehot[f] for f in slices}, data.lengths,
                   [names.index(n) for n in scales])


class ShearedDE(emcee.moves.DEMove):
    """emcee's differential-evolution move, proposing in the coordinates of a
    :class:`StyleShear` (module docstring). Other arguments as
    :class:`emcee.moves.DEMove`."""

    def __init__(self, shear: StyleShear, sigma: float = 1.0e-5, gamma0=None, **kwargs):
        super().__init__(sigma=sigma, gamma0=gamma0, **kwargs)
        self.shear = shear

    def get_proposal(self, s, c, random):
        fwd = self.shear.forward
        ys = np.asarray(fwd(jnp.asarray(s)), dtype=np.float64)
        yc = [np.asarray(fwd(jnp.asarray(ci)), dtype=np.float64) for ci in c]
        q, factors = super().get_proposal(ys, yc, random)
        return np.asarray(self.shear.inverse(jnp.asarray(q)), dtype=np.float64), factors
