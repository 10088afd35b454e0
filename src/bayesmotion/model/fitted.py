"""FittedHGPDM: a fitted model (immutable), its training-trial records and accessors."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.data.motion import MotionDataset
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.archive import save_model
from bayesmotion.model.data import ModelData, encode_trial
from bayesmotion.model.generate import SAMPLE_MEMORY, Transition, generate
from bayesmotion.model.logpost import LogPosterior, ar_of, constrained, trial_styles
from bayesmotion.model.predict import condition
from bayesmotion.model.transition import matched_transition

if TYPE_CHECKING:
    from bayesmotion.model.spec import HGPDM


class TrialRecord(NamedTuple):
    """What a fitted model remembers of each training trial.

    Attributes:
        name: trial name.
        labels: factor -> level.
        n_frames: frames in the trial.
        anchors: per actor, the decoding anchor (see PoseCodec.encode).
        offsets: per actor, (J, 3) bone offsets of that actor's skeleton.
    """

    name: str
    labels: dict
    n_frames: int
    anchors: tuple
    offsets: tuple


def trial_records(dataset: MotionDataset, codecs, root_mode) -> tuple[TrialRecord, ...]:
    out = []
    for t in dataset:
        enc = encode_trial(codecs, t, root_mode)
        out.append(TrialRecord(t.name, dict(t.labels), t.n_frames,
                               tuple(np.asarray(e.anchor) for e in enc),
                               tuple(np.asarray(m.skeleton.offsets) for m in t.actors)))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class FittedHGPDM:
    """A hierarchical GPDM at its MAP estimate.

    Attributes:
        spec: the resolved HGPDM specification.
        params: unconstrained MAP parameters (see bayesmotion.model.params).
        codecs: per actor slot, the codec between motions and Y (a PoseCodec, or an
            AffectiveCodec for ``pose_space="affective"``).
        levels: factor -> ordered level names.
        data: the training data the posterior conditions on.
        trials: per training trial, a TrialRecord.
        fps: frame rate of the training data.
        diagnostics: convergence diagnostics of the fit.
        calibration: what :func:`bayesmotion.emotion.evidence.calibrate_evidence` learned from
            recordings held out of the fit: ``effective_frames`` (n_eff,
            :mod:`bayesmotion.emotion.evidence`), the log scores and the number of recordings;
            empty when not calibrated.
    """

    spec: HGPDM
    params: dict
    codecs: tuple
    levels: dict
    data: ModelData
    trials: tuple
    fps: float
    diagnostics: dict = field(default_factory=dict)
    calibration: dict = field(default_factory=dict)
    _cache: dict = field(default_factory=dict, init=False, repr=False)

    # ------------------------------------------------------------------ accessors
    @property
    def predictor_rows(self) -> int:
        """Rows each conditioned layer holds: the training frames, or for a sparse model its
        inducing points (at most the frames)."""
        N = len(self.data.trial_of_frame)
        return N if self.spec.inducing is None else min(N, self.spec.inducing)

    @property
    def n_actors(self) -> int:
        return len(self.codecs)

    @property
    def log_posterior_fn(self) -> LogPosterior:
        return LogPosterior(self.spec, self.data)

    def _jitted(self, name: str):
        """The log-posterior's ``__call__`` / ``layer_terms``, jitted once per model (run
        eagerly, op by op, they spend seconds compiling every operation)."""
        key = "jit_" + name
        if key not in self._cache:
            lp = self.log_posterior_fn
            self._cache[key] = jax.jit(lp if name == "call" else getattr(lp, name))
        return self._cache[key]

    def log_posterior(self, params: dict | None = None, jitter: float = 1e-8) -> float:
        """Joint log-posterior (eq. 12) at ``params`` (default: the MAP)."""
        p = self.params if params is None else params
        return float(self._jitted("call")({k: jnp.asarray(v) for k, v in p.items()}, jitter))

    def layer_terms(self, jitter: float = 1e-8) -> dict[str, float]:
        terms = self._jitted("layer_terms")(
            {k: jnp.asarray(v) for k, v in self.params.items()}, jitter)
        return {k: float(v) for k, v in terms.items()}

    @property
    def hyperparameters(self) -> dict[str, np.ndarray]:
        """gamma, beta, alpha (constrained, positive) and, with the default stable dynamics,
        ``ar``: the autoregression's coefficients (a_1, .., a_o)."""
        h = constrained(self.params, self.spec.mapping_noise_floor)
        out = {k: np.asarray(v) for k, v in h.items()}
        ar = ar_of(self.params)
        if ar is not None:
            out["ar"] = np.asarray(ar)
        return out

    def styles(self) -> dict[str, np.ndarray]:
        """factor -> (R, K_f) style vector of every training trial (its level's vector)."""
        return {k: np.asarray(v) for k, v in trial_styles(self.params, self.data).items()}

    def trial_slices(self) -> list[slice]:
        ends = np.cumsum(self.data.lengths)
        return [slice(int(e - n), int(e)) for e, n in zip(ends, self.data.lengths, strict=True)]

    def latents(self, trial: int) -> dict[str, np.ndarray]:
        """X (A, T, Q_X) and I (T, Q_I) of training trial ``trial``."""
        sl = self.trial_slices()[trial]
        return {"X": np.asarray(self.params["X"][:, sl]), "I": np.asarray(self.params["I"][sl])}

    def skeleton(self, actor: int = 0, trial: int | None = None) -> Skeleton:
        """The skeleton of an actor slot, with the bone offsets of a training trial."""
        sk = self.codecs[actor].skeleton
        if trial is None:
            return sk
        key = ("skeleton", actor, trial)  # skeletons are immutable: build each one once
        if key not in self._cache:
            self._cache[key] = sk.with_offsets(self.trials[trial].offsets[actor])
        return self._cache[key]

    def level_index(self, factor: str, level: str) -> int:
        if factor not in self.levels:
            raise BayesmotionError(f"model has no style factor {factor!r}; it has "
                                   f"{list(self.levels)}")
        if level not in self.levels[factor]:
            raise BayesmotionError(f"unknown {factor} {level!r}; the model knows "
                                   f"{list(self.levels[factor])}")
        return self.levels[factor].index(level)

    def with_params(self, params: dict) -> FittedHGPDM:
        """This model at other parameters; its evidence calibration, learned at the old ones,
        is dropped."""
        return replace(self, params={k: np.asarray(v) for k, v in params.items()},
                       calibration={})

    def predictor(self):
        """Every layer conditioned on the training data at the MAP (cached: the parameters of
        a fitted model never change; :meth:`with_params` returns a new model)."""
        if "predictor" not in self._cache:
            self._cache["predictor"] = condition(self)
        return self._cache["predictor"]

    # ------------------------------------------------------------------ generation
    def generate(self, emotion="neutral", couple=None, n_frames: int = 100, n_samples: int = 0,
                 start=None, seed: int = 0, sample_memory: int = SAMPLE_MEMORY,
                 lookahead: float = 0.0, dynamics_style: str = "requested", **styles):
        """Generate motion top-down with predictive uncertainty.

        Args:
            emotion: a level name, a coordinate vector over the emotion levels (convex
                combinations interpolate; anything off the simplex extrapolates and is flagged
                in ``Rollout.extrapolated``), a (T, K) array, or a ``Transition``.
            couple: likewise for the couple factor (default: the first couple).
            n_frames: frames to generate, including the ``order`` start frames.
            n_samples: stochastic rollouts drawn from the dynamics' predictive distribution.
            start: training-trial index (default: the longest trial with the requested labels
                at the first frame, the first of equally long ones),
                ``"prior"`` (zero latent state), or an (order, Q_I) latent array.
            seed: PRNG seed of the samples.
            sample_memory: steps of its own path (at most 256) each step of a sampled rollout
                is conditioned on besides the training data, as if they were training data (0:
                each step drawn given the training data alone); only with ``n_samples`` > 0.
            lookahead: weight of the look-ahead that keeps long rollouts on the training
                latents (:func:`bayesmotion.model.generate.lookahead_step`): each step's
                mean also lowers the next step's predictive variance, weighted so. 0 (the
                default) rolls out the plain predictive means. With a periodic model
                (``HGPDM(periodic=True)``) and ``lookahead=10`` the Bandai walks keep
                walking and keep their emotion over 1,000 frames (docs/model.md,
                ``benchmarks/results/synthesis.json``). Not with ``sample_memory``.
            dynamics_style: ``"requested"`` (default): the dynamics and the interaction
                mapping both run at the requested style coordinates, as in the model.
                ``"nearest"``: the dynamics runs at the trained level nearest the coordinates
                (per frame, the largest coordinate's) and only the mapping from the latent
                state to the actors' latents at the requested coordinates, so a rollout
                between emotions follows one emotion's learned trajectory and is modulated
                towards the other by the mapping. At one-hot coordinates both are the same.
                On the Bandai walks the mixed rollouts then stay on the training latents and
                their clip features move from the neutral's to the emotion's in proportion
                to the coordinate (docs/model.md, emotion interpolation; ``benchmarks/
                results/study_interpolation_shared_latents_synthesis_setup_nearest_dynamics
                .json``).
                ``"registered"``: every level with weight runs at its own level from one of
                its own training trials (the same content where the labels allow), and the
                levels' rollouts are aligned in time by dynamic time warping of their poses
                and blended by the coordinates in every layer
                (:mod:`bayesmotion.model.registration`): the multifactor kernel's mean,
                linear in the coordinates, with each level's part read on that level's own
                path. Constant coordinates along one factor; ``start`` a trial index of the
                largest weight's level, or None. On the Bandai walks the cycle-averaged
                emotion strength of Ho et al. then follows the coordinate (Spearman 0.93,
                calibration error 0.20; ``benchmarks/results/study_interpolation_shared_
                latents_synthesis_setup_registered_dynamics.json``).
            **styles: values for any other style factor of the model.
        Returns:
            a :class:`bayesmotion.model.rollout.Rollout`.
        """
        values = {"emotion": emotion, "couple": couple, **styles}
        matched = [f for f, v in values.items() if isinstance(v, Transition) and v.match]
        if matched:
            if len(matched) > 1:
                raise BayesmotionError(f"at most one matched Transition per rollout, got "
                                       f"{len(matched)} ({', '.join(matched)})")
            f = matched[0]
            if f not in self.levels:
                raise BayesmotionError(f"model has no style factor {f!r}")
            others = {k: v for k, v in values.items()
                      if k != f and k in self.levels and v is not None}
            return matched_transition(self, f, values[f], n_frames, n_samples, start, seed,
                                      lookahead=lookahead, sample_memory=sample_memory,
                                      dynamics_style=dynamics_style, **others)
        return generate(self, emotion, couple, n_frames, n_samples, start, seed,
                        sample_memory=sample_memory, lookahead=lookahead,
                        dynamics_style=dynamics_style, **styles)

    def with_calibration(self, calibration: dict) -> FittedHGPDM:
        """This model with the emotion evidence's calibration ``calibration`` (at least
        ``effective_frames`` > 0; made by :func:`bayesmotion.emotion.evidence.calibrate_evidence`).
        """
        n_eff = calibration.get("effective_frames") if isinstance(calibration, dict) else None
        if isinstance(n_eff, bool) or not isinstance(n_eff, int | float) or not n_eff > 0 \
                or not np.isfinite(n_eff):
            raise BayesmotionError(f"a calibration needs effective_frames, a finite number > 0; "
                                   f"got {n_eff!r}")
        return replace(self, calibration=dict(calibration))

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        """Write the model as .npz arrays + JSON metadata, atomically, without pickle."""
        save_model(self, path)

    def to_device(self):
        """Parameters as JAX arrays (for use inside jitted code)."""
        return jax.tree_util.tree_map(jnp.asarray, self.params)
