"""EmotionPosterior: the posterior over a clip's emotion coordinates, its summaries (label
probabilities, label sets, credible regions) and its arviz view."""

from __future__ import annotations

from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.diagnostics import import_arviz


def top_level(probabilities, tie_break=None) -> int:
    """The index of the most probable level; ties (an answer shrunk to a flat prior) go to the
    tied level that ``tie_break`` (e.g. the in-distribution probabilities) favours, or to the
    first when it is None."""
    p = np.asarray(probabilities, dtype=np.float64)
    if tie_break is None:
        return int(np.argmax(p))
    top = np.flatnonzero(p >= p.max() - 1e-12 * max(p.max(), 1e-300))
    return int(top[np.argmax(np.asarray(tie_break, dtype=np.float64)[top])])


@dataclass(eq=False)
class EmotionPosterior:
    """Posterior over a clip's emotion coordinates (and couple style when it was inferred).

    Attributes:
        levels: emotion level names (coordinate order).
        samples: (n_chains, n_draws, K) emotion coordinates on the simplex.
        couple_levels / couple_samples: the same for the couple factor, or None.
        latents: X (A, T, Q_X), I (T, Q_I) at the MAP, with X_sd, I_sd (diagonal Laplace).
        log_prob: (n_chains, n_draws). info: n_frames, mirrored (per actor: the model's
            canonical side mirrored the clip), seconds, acceptance, tau, map objective,
            likelihood_power; with level evidence also level_log_evidence,
            level_probabilities, level_objectives, level_iterations (each level's
            projection: -log p at its end and its L-BFGS iterations), effective_frames,
            evidence_calibrated, evidence_power, probabilities_in_distribution,
            in_distribution_weight, level_prior; ood.
        log_likelihood: emotion coordinates (n, K) -> (n,) the clip's untempered
            log-likelihood (closed simplex), when the emotion was the only inferred factor of a
            single model; None otherwise (pooled draws, or the couple inferred too). It gives the
            highest-density credible regions (:meth:`hpd_contains`).
        prior_concentration: the emotion's Dirichlet prior.
        out_of_distribution: the clip lies outside the training data
            (:mod:`bayesmotion.emotion.ood`; the evidence is in ``info["ood"]``): its label
            probabilities are shrunk towards the prior (``info["in_distribution_weight"]``),
            and its coordinates are the model's nearest explanation, not evidence about the
            clip.
        label_probabilities: (K,) the posterior over which level generated the clip
            (``emotion_starts="vertices"``: the levels' evidence weighed by the effective
            frames per recording, :mod:`bayesmotion.emotion.evidence`, then shrunk towards the
            prior as far as the clip is out of distribution, :mod:`bayesmotion.emotion.ood`),
            which :attr:`probabilities` returns; None without level evidence (then the
            samples' largest coordinate counts).
    """

    levels: tuple
    samples: np.ndarray
    latents: dict
    log_prob: np.ndarray
    couple_levels: tuple | None = None
    couple_samples: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    log_likelihood: object = None
    prior_concentration: np.ndarray | None = None
    out_of_distribution: bool = False
    label_probabilities: np.ndarray | None = None
    _idata: object = None
    _sample_logp: object = None
    _sample_loglik: object = None

    def _flat(self):
        return self.samples.reshape(-1, self.samples.shape[-1])

    @property
    def mean(self) -> np.ndarray:
        """(K,) posterior mean coordinates."""
        return self._flat().mean(0)

    def interval(self, q: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
        """Equal-tailed central ``q`` credible interval of each coordinate: (lower, upper)."""
        _check_level(q)
        lo, hi = np.quantile(self._flat(), [0.5 - q / 2, 0.5 + q / 2], axis=0)
        return lo, hi

    def region_contains(self, coords, q: float = 0.9) -> bool:
        """Whether ``coords`` lie inside the central ``q`` credible region (an ellipsoid).

        Each sample's Mahalanobis distance from the posterior mean (first K - 1 coordinates, the
        last is fixed by the simplex; sample covariance) is computed; the region holds the
        fraction ``q`` of samples closest to the mean. Unlike :meth:`interval`, the region can
        contain a vertex of the simplex, which is where a categorical label's true coordinates
        lie: equal-tailed intervals of a posterior on the open simplex never reach 0 or 1.
        """
        _check_level(q)
        c = self._coords(coords, on_simplex=True)
        flat = self._flat()[:, :-1]
        if np.all(flat == flat[0]):  # degenerate samples: the region is their single point
            return bool(np.all(c == flat[0]))
        dist = self._mahalanobis2()
        return bool(dist(c) <= np.quantile(dist(flat), q))

    def log_density(self, coords) -> np.ndarray:
        """Unnormalised log posterior density on the simplex (tempered when the likelihood power
        is not 1) at coordinates (K,) or (n, K): eta log p(clip | w) + log Dirichlet(w)."""
        W = self._simplex_points(coords)
        out = self._tempered(np.asarray(self.log_likelihood(W)), W)
        return out if np.ndim(coords) == 2 else out[0]

    def _tempered(self, loglik, W):
        """eta * loglik + log Dirichlet prior at W (n, K)."""
        import numpyro.distributions as dist

        conc = (np.ones(len(self.levels)) if self.prior_concentration is None
                else self.prior_concentration)
        prior = np.asarray(dist.Dirichlet(jnp.asarray(conc)).log_prob(
            jnp.clip(jnp.asarray(W), 1e-300, 1.0)))
        return self.info.get("likelihood_power", 1.0) * loglik + prior

    def _simplex_points(self, coords) -> np.ndarray:
        if self.log_likelihood is None:
            raise BayesmotionError("no density kept for this posterior (pooled over model draws, "
                                   "or the couple inferred too): use region_contains")
        W = np.atleast_2d(np.asarray(coords, dtype=np.float64))
        if W.ndim != 2 or W.shape[1] != len(self.levels) or not _on_simplex(W):
            raise BayesmotionError(f"coords must be points of the {len(self.levels)}-level "
                                   f"simplex (non-negative, summing to 1)")
        return W

    def _samples_loglik(self):
        if self._sample_loglik is None:
            self._sample_loglik = np.asarray(self.log_likelihood(self._simplex_points(
                self._flat())))
        return self._sample_loglik

    def _samples_log_density(self):
        if self._sample_logp is None:
            self._sample_logp = self._tempered(self._samples_loglik(), self._flat())
        return self._sample_logp

    def hpd_contains(self, coords, q: float = 0.9) -> bool:
        """Whether the point ``coords`` (K,) lies in the highest-posterior-density ``q``
        credible region: the posterior density there is at least the (1 - q) quantile of the
        density at the samples. Unlike the ellipsoid of :meth:`region_contains` it follows the
        posterior's shape on the simplex, and a vertex is inside whenever the density there is
        high enough."""
        if np.ndim(coords) != 1:
            raise BayesmotionError("hpd_contains takes one point of the simplex, shape (K,)")
        return bool(self.log_density(coords) >= np.quantile(self._samples_log_density(), 1 - q))

    def loglik_drop(self, coords) -> float:
        """The clip's untempered log-likelihood at its best point (the samples and ``coords``)
        minus at ``coords``, >= 0. For a well-specified model, twice it is about chi-square with
        K - 1 degrees of freedom at a draw; it does not depend on the likelihood power the
        samples were drawn with (the statistic of
        :func:`bayesmotion.evaluation.calibration.calibrate_likelihood_power` for highest-density
        regions)."""
        W = self._simplex_points(coords)
        if W.shape[0] != 1:
            raise BayesmotionError("loglik_drop takes one point of the simplex, shape (K,)")
        at = float(np.asarray(self.log_likelihood(W))[0])
        return float(max(self._samples_loglik().max(), at) - at)

    def mahalanobis2(self, coords) -> float:
        """Squared Mahalanobis distance of ``coords`` from the posterior mean, in the posterior's
        covariance (the metric of :meth:`region_contains`). For a Gaussian posterior it is
        chi-square with K - 1 degrees of freedom at a draw; tempering the likelihood by eta
        scales it by about eta
        (:func:`bayesmotion.evaluation.calibration.calibrate_likelihood_power`)."""
        return float(self._mahalanobis2()(self._coords(coords)))

    def _coords(self, coords, on_simplex: bool = False):
        c = np.asarray(coords, dtype=np.float64)
        if c.shape != (len(self.levels),):
            raise BayesmotionError(f"coords must have {len(self.levels)} entries, got {c.shape}")
        if on_simplex and not _on_simplex(c):
            raise BayesmotionError(f"coords must lie on the simplex (>= 0, summing to 1), got "
                                   f"{c.tolist()}")
        return c[:-1]

    def _mahalanobis2(self):
        flat = self._flat()[:, :-1]
        mu = flat.mean(0)
        cov = np.atleast_2d(np.cov(flat, rowvar=False))
        prec = np.linalg.pinv(cov + 1e-12 * np.trace(cov) * np.eye(cov.shape[0]))
        return lambda x: np.einsum("...i,ij,...j->...", x - mu, prec, x - mu)

    def label_set(self, q: float = 0.9) -> tuple[str, ...]:
        """The smallest set of levels whose ``probabilities`` add up to at least ``q``."""
        p = self.probabilities
        order = np.argsort(-p, kind="stable")
        return tuple(self.levels[i] for i in order[:label_set_size(p, q)])

    @property
    def probabilities(self) -> np.ndarray:
        """(K,) posterior probability of each level: :attr:`label_probabilities` when the
        levels' evidence was computed, else the probability that each category is the largest
        coordinate of the samples."""
        if self.label_probabilities is not None:
            return np.asarray(self.label_probabilities)
        k = np.argmax(self._flat(), 1)
        return np.bincount(k, minlength=len(self.levels)) / k.size

    @property
    def label(self) -> str:
        """The most probable level; ties (an answer shrunk to a flat prior) go to the level the
        evidence favours (``info["probabilities_in_distribution"]``)."""
        return self.levels[top_level(self.probabilities,
                                     self.info.get("probabilities_in_distribution"))]

    @property
    def coordinate_entropy(self) -> float:
        """Differential entropy (nats) of the emotion coordinates, in the Gaussian approximation
        of the samples of the first K - 1 coordinates (the simplex's chart; the last coordinate
        is 1 minus their sum): 0.5 log det(2 pi e Cov). It keeps falling as a posterior sharpens
        after :attr:`entropy` (of the label probabilities) has reached 0."""
        s = self._flat()[:, :-1]
        C = np.atleast_2d(np.cov(s, rowvar=False))
        sign, logdet = np.linalg.slogdet(2 * np.pi * np.e * C)
        return float(0.5 * logdet) if sign > 0 else float("-inf")

    @property
    def entropy(self) -> float:
        """Entropy (nats) of ``probabilities``: 0 when certain, log K when uninformed."""
        p = self.probabilities
        p = p[p > 0]
        return float(-np.sum(p * np.log(p)))

    @property
    def idata(self):
        az = import_arviz()

        if self._idata is None:
            post = {"emotion": self.samples}
            coords = {"emotion_level": list(self.levels)}
            dims = {"emotion": ["emotion_level"]}
            if self.couple_samples is not None:
                post["couple"] = self.couple_samples
                coords["couple_level"] = list(self.couple_levels)
                dims["couple"] = ["couple_level"]
            import warnings

            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="More chains")
                self._idata = az.from_dict(posterior=post, sample_stats={"lp": self.log_prob},
                                           coords=coords, dims=dims)
            # lp is the tempered log-density when the likelihood power is not 1
            self._idata.posterior.attrs["likelihood_power"] = float(
                self.info.get("likelihood_power", 1.0))
        return self._idata

    def __str__(self) -> str:
        p = self.probabilities
        lo, hi = self.interval(0.9)
        coords = ", ".join(f"{l}={m:.2f} [{a:.2f}, {b:.2f}]"
                           for l, m, a, b in zip(self.levels, self.mean, lo, hi, strict=True))
        eta = self.info.get("likelihood_power", 1.0)
        tempered = "" if eta == 1.0 else f"; likelihood power {eta:.3g}"
        ood = "; OUT OF DISTRIBUTION" if self.out_of_distribution else ""
        unseen = self.info.get("unseen_levels") or {}
        unseen = f"; never seen with the given styles: {', '.join(unseen)}" if unseen else ""
        return (f"{self.label} (P={p.max():.2f}; {self.info.get('n_frames', '?')} frames"
                f"{tempered}{ood}{unseen}); mean {coords}")

    __repr__ = __str__


def label_set_size(probabilities, q: float) -> int:
    """Size of the smallest set of levels whose probabilities add up to at least ``q`` (all of
    them when rounding keeps the total below ``q``)."""
    p = np.sort(np.asarray(probabilities, dtype=np.float64))[::-1]
    return int(min(np.searchsorted(np.cumsum(p), q - 1e-12) + 1, p.size))


def _on_simplex(W) -> bool:
    """Every row non-negative and summing to 1 (to 1e-9)."""
    W = np.asarray(W)
    return bool(np.all(W >= 0) and np.all(np.abs(W.sum(-1) - 1) <= 1e-9))


def _check_level(q) -> None:
    if not isinstance(q, int | float | np.floating) or not 0 < q < 1:
        raise BayesmotionError(f"the credible level q must lie in (0, 1), got {q!r}")


def pool_posteriors(parts: list[EmotionPosterior]) -> EmotionPosterior:
    """Mixture over posterior draws: stack the chains of every part."""
    first = parts[0]
    n = min(p.samples.shape[1] for p in parts)
    cat = lambda xs: np.concatenate([x[:, -n:] for x in xs])
    info = dict(first.info)
    info.update(seconds=sum(p.info["seconds"] for p in parts), n_model_draws=len(parts),
                n_samples=sum(p.info["n_samples"] for p in parts),
                ess=sum(p.info["ess"] for p in parts))
    # the mixture over draws: its level probabilities are the draws' mean, and so are the
    # unshrunk ones and the evidence weight; every draw's out-of-distribution check is kept
    probs = (np.mean([p.label_probabilities for p in parts], axis=0)
             if all(p.label_probabilities is not None for p in parts) else None)
    if probs is not None:
        info["probabilities_in_distribution"] = np.mean(
            [p.info["probabilities_in_distribution"] for p in parts], axis=0).tolist()
        info["in_distribution_weight"] = float(np.mean(
            [p.info["in_distribution_weight"] for p in parts]))
    info["ood_per_draw"] = [p.info.get("ood") for p in parts]
    return EmotionPosterior(first.levels, cat([p.samples for p in parts]), first.latents,
                            cat([p.log_prob for p in parts]), first.couple_levels,
                            None if first.couple_samples is None else cat(
                                [p.couple_samples for p in parts]), info,
                            out_of_distribution=any(p.out_of_distribution for p in parts),
                            label_probabilities=probs)
