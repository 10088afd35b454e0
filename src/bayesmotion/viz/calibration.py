"""The reliability diagram of label probabilities, with consistency bars.

Made without pyplot, as :mod:`bayesmotion.viz.plots`: display ``ax.figure`` in a notebook.
"""

from __future__ import annotations

import os

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from bayesmotion.evaluation.calibration import calibration_consistency
from bayesmotion.viz.plots import save_figure


def plot_reliability(probabilities, truth, path: str | os.PathLike | None = None, *,
                     ax: Axes | None = None, n_bins: int = 10, n_draws: int = 2000,
                     level: float = 0.9, seed: int = 0, title: str | None = None,
                     dpi: float = 100, labels=None) -> Axes:
    """Reliability diagram: each bin's accuracy against its mean confidence, with the range a
    calibrated posterior's accuracy would take in that bin (its consistency bar, Broecker and
    Smith 2007, :func:`bayesmotion.evaluation.calibration.calibration_consistency`).

    A point inside its bar is what calibration itself produces with that many clips; a point
    outside is evidence of over- (below the diagonal) or under-confidence. Marker area grows
    with the bin's count. The title gives the ECE, a calibrated posterior's mean ECE with the
    same answers, and the p-value.

    Args:
        probabilities: (n, K) label probabilities of n clips (e.g. each
            :class:`~bayesmotion.EmotionPosterior`'s ``probabilities`` from leave-one-out).
        truth: (n,) true level indices.
        path: also save the figure here (PNG by default), atomically.
        ax: a 2-D Axes to draw into; a new figure when None.
        n_bins: number of equal-width confidence bins.
        n_draws: calibrated data sets drawn for the bars and the p-value.
        level: coverage of each bin's consistency bar.
        seed: of the draws.
        title: Axes title (default: the ECE line).
        dpi: resolution of the saved file.
        labels: (n,) the answered level indices, each a most probable level (default the
            first most probable; see :func:`~bayesmotion.evaluation.calibration.reliability`).
    Returns:
        the Axes.
    """
    c = calibration_consistency(probabilities, truth, n_bins, n_draws, level, seed, labels)
    if ax is None:
        fig = Figure(figsize=(4.5, 4.5), dpi=dpi, layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1], color="0.6", linewidth=1, linestyle="--", label="calibrated")
    conf = np.array([b["confidence"] for b in c["bins"]])
    acc = np.array([b["accuracy"] for b in c["bins"]])
    lo, hi = np.array([b["accuracy_interval"] for b in c["bins"]]).T
    ax.vlines(conf, lo, hi, color="tab:blue", alpha=0.4, linewidth=6,
              label=f"{100 * level:.0f}% if calibrated")
    count = np.array([b["count"] for b in c["bins"]])
    ax.scatter(conf, acc, s=20 + 200 * count / count.max(), color="tab:red", zorder=3,
               label="observed")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("confidence (top label's probability)")
    ax.set_ylabel("accuracy")
    mean = c["ece_if_calibrated"]["mean"]
    ax.set_title(title if title is not None else
                 f"ECE {c['ece']:.3f} (if calibrated: {mean:.3f}, p = {c['p_value']:.2f})",
                 fontsize="medium")
    ax.legend(fontsize="small", loc="lower right")
    if path is not None:
        save_figure(ax.figure, path, dpi)
    return ax
