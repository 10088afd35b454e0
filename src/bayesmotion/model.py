"""The hierarchical GPDM of Taubert et al. (2012) as one log-posterior.

Layers (paper symbols -> code):

* bottom: ``Y_a ~ GP(X_a)`` for each actor a with one shared ``gamma`` (eq. 1-5);
* interaction: ``[X_1, X_2] ~ GP(I)`` with the multifactor style kernel (``beta``, style ``S``);
* dynamics: second-order (or first-order) GPDM on ``I`` with linear + RBF kernel times the style
  factors (``alpha``, eq. 9-11); the chain restarts at each trial.

The joint negative log-posterior (eq. 12) is

    -log p = -sum_a log N(Y_a | 0, K_Y(X_a))          (bottom, eq. 1-3, per column)
             -log N([X_1 X_2] | 0, K_X(I, S))         (interaction)
             -log N(I_out | 0, K_I(I_in, S))          (dynamics, eq. 11)
             -sum_trials log N(I_first | 0, init_var) (restart prior, eq. 9)
             -log p(gamma, beta, alpha) - log p(S)    (priors, see bayesmotion.params)

For one-actor data the interaction layer maps I to X_1 alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import layers
from .data.affective_codec import check_pose_space, fit_codec
from .data.motion import MotionDataset
from .errors import BayesmotionError
from .params import (
    STYLE_PREFIX,
    Priors,
    StylePrior,
    log_prior_hyper,
    log_prior_style,
    style_to_simplex,
)

DEFAULT_FACTORS = ("couple", "emotion")


class ModelData(NamedTuple):
    """Everything the log-posterior conditions on, as arrays (static shapes).

    Attributes:
        Y: per actor, (N, D_a) normalised poses of all trials stacked.
        onehot: factor -> (R, K_f) one-hot labels of the training trials.
        trial_of_frame: (N,) trial index of every frame.
        lengths: (R,) frames per trial.
    """

    Y: tuple[np.ndarray, ...]
    onehot: dict[str, np.ndarray]
    trial_of_frame: np.ndarray
    lengths: np.ndarray


@dataclass(frozen=True)
class HGPDM:
    """Specification of a hierarchical GPDM (immutable; ``fit`` returns a FittedHGPDM).

    Attributes:
        latent_dim: Q_X, dimension of each actor's latent X (paper: 6).
        interaction_dim: Q_I, dimension of the joint latent I (paper: 6).
        order: dynamics order, 1 or 2 (paper: 2).
        interaction_factors: style factors entering the interaction kernel (default: those of
            ("couple", "emotion") present in the data).
        dynamics_factors: style factors entering the dynamics kernel (same default).
        root_mode: root translation representation ("partner" for two actors, "heading" for
            one, by default); see bayesmotion.data.representation.
        scaling: per-channel scaling of Y ("type" or "channel").
        rest_frames: turn each joint's frame to its mean rotation over the training motions
            before encoding (see bayesmotion.data.representation; for rigs near gimbal lock,
            such as Bandai's spine). Stored with the model, so new clips get the same frames.
        canonical_side: mirror every one-actor motion that moves to the actor's right before
            encoding, training clips and new clips alike (label-free;
            bayesmotion.data.mirror.canonical_side); generated motion is on the left side.
        pose_space: what the bottom layer models: "angles" (joint angles and the root's
            motion, :class:`~bayesmotion.data.representation.PoseCodec`; the model generates
            motion) or "affective" (the 18 affective pose features of every frame,
            :mod:`bayesmotion.data.affective_codec`; invariant to the body's position, heading
            and size, for inferring emotion across actions; such a model cannot generate
            motion; ``rest_frames`` and a ``scaling`` other than the default are refused:
            the features are standardised one by one).
        priors: prior settings.
    """

    latent_dim: int = 6
    interaction_dim: int = 6
    order: int = 2
    interaction_factors: tuple[str, ...] | None = None
    dynamics_factors: tuple[str, ...] | None = None
    root_mode: str | None = None
    scaling: str = "type"
    rest_frames: bool = False
    canonical_side: bool = False
    pose_space: str = "angles"
    priors: Priors = field(default_factory=Priors)

    def __post_init__(self):
        check_pose_space(self.pose_space, self.rest_frames, self.scaling)
        if self.order not in (1, 2):
            raise BayesmotionError(f"order must be 1 or 2, got {self.order}")
        if self.latent_dim < 1 or self.interaction_dim < 1:
            raise BayesmotionError("latent dimensions must be positive")

    def resolved(self, dataset: MotionDataset) -> HGPDM:
        """Fill defaults that depend on the data (factors, root mode)."""
        present = tuple(f for f in DEFAULT_FACTORS if f in dataset.levels)
        spec = self
        for name in ("interaction_factors", "dynamics_factors"):
            val = getattr(spec, name)
            val = present if val is None else tuple(val)
            missing = [f for f in val if f not in dataset.levels]
            if missing:
                raise BayesmotionError(f"{name}: dataset has no labels for {missing}; "
                                       f"it has {list(dataset.levels)}")
            spec = replace(spec, **{name: val})
        if spec.root_mode is None:
            spec = replace(spec, root_mode="partner" if dataset.n_actors == 2 else "heading")
        return spec

    @property
    def factors(self) -> tuple[str, ...]:
        """All style factors used anywhere, in a fixed order."""
        out = []
        for f in (*self.interaction_factors, *self.dynamics_factors):
            if f not in out:
                out.append(f)
        return tuple(out)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("latent_dim", "interaction_dim", "order",
                                             "root_mode", "scaling", "rest_frames",
                                             "canonical_side", "pose_space")}
        d["interaction_factors"] = list(self.interaction_factors or ())
        d["dynamics_factors"] = list(self.dynamics_factors or ())
        d["priors"] = self.priors.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> HGPDM:
        d = dict(d)
        d["priors"] = Priors.from_dict(d["priors"])
        d["interaction_factors"] = tuple(d["interaction_factors"])
        d["dynamics_factors"] = tuple(d["dynamics_factors"])
        return cls(**d)

    def fit(self, dataset: MotionDataset, **kwargs):
        """MAP fit; see :func:`bayesmotion.fit.fit_hgpdm` for the options."""
        from .fit import fit_hgpdm

        return fit_hgpdm(self, dataset, **kwargs)


# --------------------------------------------------------------------------- data preparation
def fit_codecs(spec: HGPDM, dataset: MotionDataset) -> tuple:
    """One codec per actor slot (of ``spec.pose_space``), fitted on all training trials."""
    if spec.canonical_side and dataset.n_actors != 1:
        raise BayesmotionError(f"canonical_side mirrors one-actor clips; this dataset has "
                               f"{dataset.n_actors} actors per trial, and mirroring each alone "
                               f"would break their interaction")
    codecs = []
    for a in range(dataset.n_actors):
        motions = [t.actors[a] for t in dataset]
        partners = [t.actors[1 - a] for t in dataset] if spec.root_mode == "partner" else None
        if spec.root_mode == "partner" and dataset.n_actors != 2:
            raise BayesmotionError("root_mode='partner' needs two-actor trials")
        codecs.append(fit_codec(spec.pose_space, motions, partners, spec.root_mode,
                                spec.scaling, spec.rest_frames, spec.canonical_side))
    return tuple(codecs)


def encode_trial(codecs, trial, root_mode):
    """Per actor (Y (T, D_a), anchor) of one trial."""
    out = []
    for a, codec in enumerate(codecs):
        partner = trial.actors[1 - a] if root_mode == "partner" else None
        out.append(codec.encode(trial.actors[a], partner))
    return out


def onehot_labels(dataset: MotionDataset, factors) -> dict[str, np.ndarray]:
    out = {}
    for f in factors:
        levels = dataset.levels[f]
        labs = dataset.labels(f)
        if any(l is None for l in labs):
            raise BayesmotionError(f"every trial needs a {f!r} label")
        out[f] = np.eye(len(levels))[[levels.index(l) for l in labs]]
    return out


def prepare_data(spec: HGPDM, dataset: MotionDataset, codecs) -> ModelData:
    enc = [encode_trial(codecs, t, spec.root_mode) for t in dataset]
    Y = tuple(np.concatenate([e[a].Y for e in enc]) for a in range(dataset.n_actors))
    lengths = np.array([t.n_frames for t in dataset])
    if lengths.min() <= spec.order + 1:
        raise BayesmotionError(f"every trial needs more than {spec.order + 1} frames; the "
                               f"shortest has {lengths.min()}")
    return ModelData(Y, onehot_labels(dataset, spec.factors),
                     np.repeat(np.arange(len(dataset)), lengths), lengths)


# --------------------------------------------------------------------------- the log-posterior
def trial_styles(params: dict, data: ModelData) -> dict[str, jnp.ndarray]:
    """factor -> (R, K_f) style vector of every trial: its level's free vector (params holds
    one per level, (K_f, K_f - 1) unconstrained) or, when not free, its one-hot label."""
    out = {}
    for f, h in data.onehot.items():
        key = STYLE_PREFIX + f
        h = jnp.asarray(h)
        out[f] = h @ style_to_simplex(params[key]) if key in params else h
    return out


def constrained(params: dict) -> dict:
    """Positive hyperparameters from their logs."""
    return {k[4:]: jnp.exp(v) for k, v in params.items() if k.startswith("log_")}


LAYERS = ("bottom", "interaction", "dynamics")


class LogPosterior:
    """The joint log-posterior of eq. 12 as a pure function of the parameter dict.

    ``LogPosterior(spec, data)(params, jitter)`` -> scalar; -inf outside the support.
    While a layer's style vectors are the fixed one-hot labels its kernel matrix is exactly
    block-diagonal by style cell and is factorised block by block (``dense=True`` forces the
    dense path; tests check both agree).
    The instance holds only static bookkeeping (indices, data), so it is safe to close over
    inside ``jit``.
    """

    def __init__(self, spec: HGPDM, data: ModelData, dense: bool = False):
        self.spec = spec
        self.dense = dense
        self.data = data
        self.index = layers.DynamicsIndex(data.lengths, spec.order)
        self.style_prior = StylePrior.around_labels(data.onehot, spec.priors.style_kappa)
        tof = data.trial_of_frame
        int_cells = layers.cell_ids([data.onehot[f][tof] for f in spec.interaction_factors])
        dyn_cells = layers.cell_ids([data.onehot[f][tof][self.index.out]
                                     for f in spec.dynamics_factors])
        # Block-diagonal plans, used while the layer's style vectors are the fixed one-hot labels
        self.int_blocks = layers.Blocks(int_cells) if int_cells.size else None
        self.dyn_blocks = layers.Blocks(dyn_cells) if dyn_cells.size else None

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
        h = constrained(params)
        X, I = params["X"], params["I"]
        A = X.shape[0]
        terms = {k: jnp.zeros(()) for k in LAYERS}
        if "bottom" in which:
            terms["bottom"] = sum(layers.gplvm_loglik(X[a], jnp.asarray(self.data.Y[a]),
                                                      h["gamma"], jitter) for a in range(A))
        if "interaction" in which:
            Z = jnp.concatenate([X[a] for a in range(A)], axis=1)
            terms["interaction"] = self._interaction(params, I, Z, h["beta"], jitter)
        if "dynamics" in which:
            terms["dynamics"] = self._dynamics(params, I, h["alpha"], jitter)
        prior = (log_prior_hyper(params, self.spec.priors, self.spec.order)
                 + log_prior_style(params, self.style_prior))
        return {**terms, "prior": prior}

    def _interaction(self, params, I, Z, beta, jitter):
        fi = self.spec.interaction_factors
        if self.dense or self.int_blocks is None or not self._fixed(params, fi):
            return layers.style_gplvm_loglik(I, Z, self.frame_styles(params, fi), beta, jitter)
        return layers.blocked_style_gplvm_loglik(I, Z, beta, self.int_blocks, jitter)

    def _dynamics(self, params, I, alpha, jitter):
        fd, v0 = self.spec.dynamics_factors, self.spec.priors.init_var
        if self.dense or self.dyn_blocks is None or not self._fixed(params, fd):
            return layers.gpdm_loglik(I, self.frame_styles(params, fd), alpha, self.index,
                                      jitter, v0)
        return layers.blocked_gpdm_loglik(I, alpha, self.index, self.dyn_blocks, jitter, v0)

    def __call__(self, params: dict, jitter=0.0, which=LAYERS) -> jnp.ndarray:
        t = self.layer_terms(params, jitter, which)
        total = t["bottom"] + t["interaction"] + t["dynamics"] + t["prior"]
        return jnp.where(jnp.isnan(total), -jnp.inf, total)


# --------------------------------------------------------------------------- initialisation
def pca(Y: np.ndarray, q: int) -> np.ndarray:
    """(N, D) -> (N, q) principal-component scores, scaled so the first has unit std."""
    Yc = Y - Y.mean(0)
    U, s, _ = np.linalg.svd(Yc, full_matrices=False)
    q_eff = min(q, s.size)
    Z = U[:, :q_eff] * s[:q_eff]
    if q_eff < q:
        Z = np.concatenate([Z, np.zeros((Y.shape[0], q - q_eff))], axis=1)
    sd = Z[:, 0].std() or 1.0
    return Z / sd


def init_params(spec: HGPDM, data: ModelData, seed: int = 0, jitter_scale: float = 1e-3):
    """PCA initialisation of X (per actor) and I (from the stacked X), default hyperparameters.

    A tiny seeded perturbation breaks exact ties (deterministic for a seed).
    """
    rng = np.random.default_rng(seed)
    X = np.stack([pca(Y, spec.latent_dim) for Y in data.Y])
    Z = np.concatenate(list(X), axis=1)
    I = pca(Z, spec.interaction_dim)
    X = X + jitter_scale * rng.standard_normal(X.shape)
    I = I + jitter_scale * rng.standard_normal(I.shape)
    var_y = float(np.mean([np.mean(Y**2) for Y in data.Y]))
    var_z = float(np.mean(Z**2))
    var_i = float(np.mean(I**2))
    o = spec.order
    return {
        "X": X,
        "I": I,
        "log_gamma": np.log([var_y, 1.0, 100.0 / var_y]),
        "log_beta": np.log([var_z, 1.0, 100.0 / var_z]),
        "log_alpha": np.log([var_i] + [1.0] * o + [0.5 / o] * o + [100.0 / var_i]),
    }


def make_value_and_grad(fn):
    """Jitted value-and-gradient of a function of (flat vector, jitter)."""
    return jax.jit(jax.value_and_grad(fn))
