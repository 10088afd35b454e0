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
scales, one ``g`` per layer:

    g(S) = sum_n w_n prod_f |s_f(n)|^2,

the weighted mean over training trials n of the style part of the layer's kernel diagonal:
``f`` runs over the layer's style factors, ``s_f(n)`` is the style vector of trial n's level,
and ``w_n`` is trial n's share of the layer's outputs (its frames in the interaction layer, its
frames after the first o in the dynamics, a periodic model's loop rows left out). The style
coordinates pass through unchanged, so ``phi`` is a shear: its Jacobian is triangular with a
unit diagonal, ``|det dphi/dx| = 1``. In ``y`` the log scales are those of the mean prior
variance itself, and the ridge is (nearly) straight.

:class:`ShearedDE` is emcee's :class:`~emcee.moves.DEMove` proposing in ``y``: it maps the
walkers (and the complementary ensemble) to ``y``, takes emcee's differential-evolution step
there, and maps the proposals back. A proposal symmetric in ``y`` under a volume-preserving
bijection is symmetric in ``x``, so the acceptance is the plain density ratio (DE's own zero
log-factor) and the chain, its files and its diagnostics stay in the model's coordinates. The
move costs one log-density per walker, as DE does. Measured in
``benchmarks/results/style_shear.json``.
"""

from __future__ import annotations

import weakref

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.gp.kernels import has_linear_term
from bayesmotion.inference.moves.rotations import style_slices
from bayesmotion.model.params import style_to_simplex

# target -> its shear (or None), so the maps compile once per run however often the moves are
# rebuilt (the adaptation's two phases, the independence block's choice)
_BUILT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class StyleShear:
    """The volume-preserving map ``phi`` of the module docstring, on flat vectors.

    Args:
        style_index: factor -> flat indices ``(K * (K - 1),)`` of its unconstrained style
            block, in C order (:func:`bayesmotion.inference.moves.style_slices`).
        onehot: factor -> ``(R, K)`` one-hot level of each training trial.
        groups: one ``(scale_index, factors, weights)`` per layer: the flat indices of the log
            output scales that multiply the layer's style factor, the sampled factors in it
            (keys of ``style_index``), and ``(R,)`` positive weights of the trials (normalised
            here). Scales and style coordinates must not overlap.

    ``forward(xs)`` maps ``(n, d)`` walkers to ``y`` and ``inverse(ys)`` back (both jitted,
    vmapped over walkers); ``log_g(x, i)`` is group ``i``'s ``log g`` at one flat vector.
    """

    def __init__(self, style_index: dict, onehot: dict, groups):
        if not style_index:
            raise ValueError("StyleShear needs at least one sampled style factor")
        self._blocks = {}
        for f, idx in style_index.items():
            oh = np.asarray(onehot[f], dtype=float)
            K = oh.shape[1]
            idx = np.asarray(idx, dtype=int).ravel()
            if idx.size != K * (K - 1):
                raise ValueError(f"factor {f!r}: {idx.size} style coordinates do not fit "
                                 f"{K} levels")
            self._blocks[f] = (jnp.asarray(idx), K, jnp.asarray(oh))
        styles = np.concatenate([np.asarray(i, dtype=int).ravel()
                                 for i in style_index.values()])
        self._groups = []
        for scale, factors, weights in groups:
            scale = np.asarray(scale, dtype=int).ravel()
            w = np.asarray(weights, dtype=float).ravel()
            if scale.size == 0 or not factors:
                raise ValueError("each group needs output-scale coordinates and style factors")
            if np.intersect1d(scale, styles).size:
                raise ValueError("the output scales and the style coordinates overlap: the map "
                                 "would not be invertible")
            unknown = [f for f in factors if f not in self._blocks]
            if unknown:
                raise ValueError(f"factors {unknown} have no style coordinates")
            if np.any(w <= 0) or any(self._blocks[f][2].shape[0] != w.size for f in factors):
                raise ValueError(f"weights must be one positive number per trial, got {w!r}")
            self._groups.append((jnp.asarray(scale), tuple(factors), jnp.asarray(w / w.sum())))
        if not self._groups:
            raise ValueError("StyleShear needs at least one group of output scales")
        self.scale_index = np.concatenate([np.asarray(g[0]) for g in self._groups])

        def forward(x):
            for i, (scale, _, _) in enumerate(self._groups):
                x = x.at[scale].add(self.log_g(x, i))
            return x

        def inverse(y):  # log g reads only the style coordinates, which phi leaves alone
            for i, (scale, _, _) in enumerate(self._groups):
                y = y.at[scale].add(-self.log_g(y, i))
            return y

        self.forward = jax.jit(jax.vmap(forward))
        self.inverse = jax.jit(jax.vmap(inverse))

    def log_g(self, x, i: int = 0):
        """``log sum_n w_n prod_f |s_f(n)|^2`` of group ``i`` at the flat vector ``x``."""
        _, factors, w = self._groups[i]
        d = 1.0
        for f in factors:
            idx, K, oh = self._blocks[f]
            s = oh @ style_to_simplex(x[idx].reshape(K, K - 1))
            d = d * jnp.sum(s * s, -1)
        return jnp.log(jnp.sum(w * d))

    @classmethod
    def for_target(cls, target) -> StyleShear | None:
        """The shear of a :class:`bayesmotion.inference.target.Target` that samples style
        vectors together with the output scales they multiply; None for any other target
        (no style vectors, styles held fixed, or a bare density). Built once per target."""
        try:
            if target not in _BUILT:
                _BUILT[target] = cls._build(target)
            return _BUILT[target]
        except TypeError:  # a target that cannot be weakly referenced or hashed
            return cls._build(target)

    @classmethod
    def _build(cls, target) -> StyleShear | None:
        model = getattr(target, "model", None)
        names = getattr(target, "names", None)
        data = getattr(model, "data", None)
        if (names is None or not hasattr(target, "unravel") or data is None
                or not hasattr(model, "params") or not hasattr(model, "spec")):
            return None  # a bare density, or a stand-in without the model's trials
        slices = style_slices(target.unravel, target.x0)
        if not slices:
            return None
        spec, lengths = model.spec, np.asarray(data.lengths, dtype=float)
        o = spec.order
        dyn_scales = ["log_alpha[0]"]
        alpha = model.params.get("log_alpha")
        if alpha is not None and has_linear_term(np.asarray(alpha), o):
            dyn_scales += [f"log_alpha[{1 + o + l}]" for l in range(o)]
        groups = []
        for scales, factors, weights in (
                (["log_beta[0]"], spec.interaction_factors, lengths),
                (dyn_scales, spec.dynamics_factors, lengths - o)):  # outputs per trial
            scales = [names.index(n) for n in scales if n in names]
            factors = [f for f in (factors or ()) if f in slices]
            if scales and factors:
                groups.append((scales, factors, weights))
        if not groups:
            return None
        return cls(slices, {f: data.onehot[f] for f in slices}, groups)


class ShearedDE(emcee.moves.DEMove):
    """emcee's differential-evolution move, proposing in the coordinates of a
    :class:`StyleShear` (module docstring). Other arguments as
    :class:`emcee.moves.DEMove`."""

    def __init__(self, shear: StyleShear, **kwargs):
        super().__init__(**kwargs)
        self.shear = shear

    def get_proposal(self, s, c, random):
        fwd = self.shear.forward
        ys = np.asarray(fwd(jnp.asarray(s)), dtype=np.float64)
        yc = [np.asarray(fwd(jnp.asarray(ci)), dtype=np.float64) for ci in c]
        q, factors = super().get_proposal(ys, yc, random)
        return np.asarray(self.shear.inverse(jnp.asarray(q)), dtype=np.float64), factors
