"""HGPDM: the specification of a hierarchical GPDM, and the estimator whose ``fit`` returns a
:class:`~bayesmotion.model.fitted.FittedHGPDM` (MAP, :mod:`bayesmotion.model.fit`).

The model itself (layers, log-posterior of eq. 12) is in :mod:`bayesmotion.model.logpost`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, replace

from bayesmotion.codecs.affective import check_pose_space
from bayesmotion.data.motion import MotionDataset
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.fit import fit_hgpdm
from bayesmotion.model.fitted import FittedHGPDM
from bayesmotion.model.params import Priors

DEFAULT_FACTORS = ("couple", "emotion")
DYNAMICS_LINEAR = ("stable", "kernel")


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
            one, by default); see bayesmotion.codecs.pose.
        scaling: per-channel scaling of Y ("type" or "channel").
        rest_frames: turn each joint's frame to its mean rotation over the training motions
            before encoding (see bayesmotion.codecs.pose; for rigs near gimbal lock,
            such as Bandai's spine). Stored with the model, so new clips get the same frames.
        canonical_side: mirror every one-actor motion that moves to the actor's right before
            encoding, training clips and new clips alike (label-free;
            bayesmotion.data.mirror.canonical_side); generated motion is on the left side.
        pose_space: what the bottom layer models: "angles" (joint angles and the root's
            motion, :class:`~bayesmotion.codecs.pose.PoseCodec`; the model generates
            motion) or "affective" (the 18 affective pose features of every frame,
            :mod:`bayesmotion.codecs.affective`; invariant to the body's position, heading
            and size, for inferring emotion across actions; such a model cannot generate
            motion; ``rest_frames`` and a ``scaling`` other than the default are refused:
            the features are standardised one by one).
        relative_to: None (default), or with ``pose_space="affective"`` a trial label such as
            "content": every frame's features are modelled relative to the mean of the
            training trials sharing that label (:mod:`bayesmotion.codecs.affective`), so that
            a model pooling several actions models how each clip departs from its action.
            Every training trial and every inferred clip needs the label; a clip whose label
            the training trials lack is reported out of distribution.
        dynamics_linear: the linear part of the dynamics' mean. "stable" (default): an
            explicit autoregression i_t = sum_l a_l i_{t-l} + f(i_{t-1}, .., i_{t-o}) with the
            coefficients a parameterised through partial autocorrelations so that only
            stationary ones exist (:func:`bayesmotion.model.params.ar_coefficients`), f the
            RBF-kernel GP; a mean rollout is then bounded at every parameter value (a stable
            linear system driven by a bounded input) and far from the data decays towards
            the origin instead of growing. "kernel": the paper's eq. 10, a linear kernel term
            sum_l alpha_lin i_{t-l}^T i'_{t-l} added to the RBF, whose implied autoregression
            nothing keeps stable (mean rollouts of real walks grow without bound within a
            few hundred frames; docs/model.md).
        dynamics_weight: multiplies the dynamics layer's log-likelihood in the objective and
            the posterior (Wang et al. 2008's balanced GPDM uses D / Q, the pose over the
            latent dimension, so the dynamics is not swamped by the many pose dimensions);
            1 (default) is the plain model. :func:`bayesmotion.infer_emotion` scores new clips
            with the plain likelihood whatever the weight. Measured on the Bandai walks in
            ``benchmarks/results/synthesis.json`` (``mechanisms``).
        inducing: None (default) for the exact model; a number M of inducing points for the
            sparse model: every layer (bottom, interaction, dynamics) replaced by Titsias's
            variational bound with M inducing inputs (at most the layer's rows), O(N M^2)
            per evaluation instead of O(N^3) (:mod:`bayesmotion.gp.sparse`, docs/model.md).
            The inducing inputs start at M evenly spaced training frames, whose style they
            keep, and are fitted with the latents; with M >= N they start at every frame and
            the bound equals the exact model.
        periodic: the motion is periodic (walks, runs): each training trial whose last o
            frames match an earlier o-frame window closer than one frame's step
            (:func:`bayesmotion.model.data.find_loops`) gets o extra dynamics rows that continue
            its last frames as that window was continued, so the dynamics learns what follows
            the end of the recording and the latent trajectory closes into a loop. Without it
            a rollout that reaches the end of its training trajectory has nothing to follow
            and drifts off the data (docs/model.md). Off by default: a gesture or a
            handshake should come to rest, not repeat.
        mapping_noise_floor: the least noise variance of the two mapping layers, bottom
            (latents X to the standardised poses Y) and interaction (I to X), in their
            outputs' units (at most 1, those outputs' scale): each noise variance is this
            floor plus a free, fitted part (:func:`bayesmotion.model.logpost.constrained`), in
            the MAP, the samplers and every prediction alike; the dynamics' noise stays free.
            0 (the default) is the plain model, whose MAP drives these noises to 1e-5-1e-7 of
            the outputs' scale on the built-in handshakes and the Bandai gestures, and whose
            generated gestures grow rougher with the fit's length (jerk 1.37x real after
            1,000 iterations, 2.50x after 3,000); with 1e-3 they stay at 0.90x and 0.83x
            and come to rest sooner, the walks are unchanged, and the run's long rollouts
            leave the training latents (docs/model.md, "A floor on the mapping layers'
            noise"; ``benchmarks/results/noise_floor.json``).
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
    relative_to: str | None = None
    dynamics_linear: str = "stable"
    dynamics_weight: float = 1.0
    inducing: int | None = None
    periodic: bool = False
    mapping_noise_floor: float = 0.0
    priors: Priors = field(default_factory=Priors)

    def __post_init__(self):
        check_pose_space(self.pose_space, self.rest_frames, self.scaling, self.relative_to)
        if self.order not in (1, 2):
            raise BayesmotionError(f"order must be 1 or 2, got {self.order}")
        if self.latent_dim < 1 or self.interaction_dim < 1:
            raise BayesmotionError("latent dimensions must be positive")
        w = self.dynamics_weight
        if (isinstance(w, bool) or not isinstance(w, int | float)
                or not (math.isfinite(w) and w > 0)):
            raise BayesmotionError(f"dynamics_weight must be a positive number, got {w!r}")
        m = self.inducing
        if m is not None:
            if isinstance(m, bool) or not isinstance(m, numbers.Integral) or m < 2:
                raise BayesmotionError(f"inducing must be None (the exact model) or a whole "
                                       f"number >= 2 of inducing points, got {m!r}")
            object.__setattr__(self, "inducing", int(m))
        if not isinstance(self.periodic, bool):
            raise BayesmotionError(f"periodic must be True or False, got {self.periodic!r}")
        object.__setattr__(self, "periodic", bool(self.periodic))
        f = self.mapping_noise_floor
        if (isinstance(f, bool) or not isinstance(f, numbers.Real)
                or not (math.isfinite(f) and 0 <= f <= 1)):
            raise BayesmotionError(f"mapping_noise_floor must be a number in [0, 1] (a noise "
                                   f"variance in the layers' output units, the standardised "
                                   f"poses and the latents), got {f!r}")
        object.__setattr__(self, "mapping_noise_floor", float(f))
        if self.dynamics_linear not in DYNAMICS_LINEAR:
            raise BayesmotionError(f"dynamics_linear must be one of {DYNAMICS_LINEAR}, got "
                                   f"{self.dynamics_linear!r}")

    @property
    def stable_dynamics(self) -> bool:
        """Whether the dynamics' linear part is the explicit stationary autoregression."""
        return self.dynamics_linear == "stable"

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
        if spec.relative_to is not None and spec.relative_to in spec.factors:
            raise BayesmotionError(f"relative_to={spec.relative_to!r} is also a style factor: "
                                   f"a label the poses are read relative to carries no style "
                                   f"left to model; drop it from the style factors")
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
                                             "canonical_side", "pose_space",
                                             "relative_to", "dynamics_linear", "dynamics_weight",
                                             "inducing", "periodic",
                                             "mapping_noise_floor")}
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
        d.setdefault("dynamics_linear", "kernel")  # files written before the option existed
        d.setdefault("dynamics_weight", 1.0)
        d.setdefault("inducing", None)
        d.setdefault("periodic", False)
        d.setdefault("mapping_noise_floor", 0.0)
        d.setdefault("relative_to", None)
        return cls(**d)

    def fit(self, dataset: MotionDataset, **kwargs) -> FittedHGPDM:
        """MAP fit; see :func:`bayesmotion.model.fit.fit_hgpdm` for the options."""
        return fit_hgpdm(self, dataset, **kwargs)
