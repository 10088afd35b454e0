"""A readable view of a posterior: one named row per sampled hyperparameter.

Each row shows the draws of one coordinate against the step, one thin line per chain (walker),
and their histogram; coordinates that are scales (every entry of gamma, beta and alpha is a
positive scale, precision or inverse length scale) are drawn on a log axis, as they span
several orders of magnitude between coordinates. Beside each row: that coordinate's rank-
normalised R-hat and bulk / tail ESS (arviz), the R-hat in red above 1.01.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from matplotlib import ticker
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.diagnostics import arviz_without_numba, import_arviz
from bayesmotion.viz.plots import save_figure

SCALES = ("gamma", "beta", "alpha")
"""Variables whose every entry is positive and drawn on a log axis."""
RHAT_OK = 1.01
MAX_CHAINS_DRAWN = 64
"""Chains (walkers) drawn in the trace panels at most; the histograms use every draw."""


def coordinate_table(post, var_names: Sequence[str] | None = None) -> list[dict]:
    """One entry per scalar coordinate: ``name`` (e.g. ``gamma1_signal``), ``var``,
    ``draws`` (chains, draws), ``log`` (drawn on a log axis), ``rhat``, ``ess_bulk``,
    ``ess_tail``."""
    az = import_arviz()

    ds = post.idata.posterior
    wanted = list(var_names or ("gamma", "beta", "alpha", "ar"))
    names = [v for v in wanted if v in ds]
    if not names:
        raise BayesmotionError(f"the posterior has none of {wanted}; it holds "
                               f"{sorted(ds.data_vars)}")
    with arviz_without_numba():
        rhat = az.rhat(ds[names])
        bulk = az.ess(ds[names], method="bulk")
        tail = az.ess(ds[names], method="tail")
    rows = []
    for v in names:
        da = ds[v]
        extra = [d for d in da.dims if d not in ("chain", "draw")]
        flat = da.stack(coordinate=extra) if extra else da.expand_dims(coordinate=[v])
        labels = [v] if not extra else [
            str(c) if not isinstance(c, tuple) else str(c[0]) if len(c) == 1
            else f"{v}[{','.join(map(str, c))}]"
            for c in flat["coordinate"].values]
        r = np.ravel(rhat[v].values)
        b, t = np.ravel(bulk[v].values), np.ravel(tail[v].values)
        for i, label in enumerate(labels):
            rows.append({"name": label, "var": v,
                         "draws": np.asarray(flat.isel(coordinate=i).transpose("chain", "draw")),
                         "log": v in SCALES, "rhat": float(r[i]), "ess_bulk": float(b[i]),
                         "ess_tail": float(t[i])})
    return rows


def _plain_log_ticks(axis, subs) -> None:
    """Log-axis ticks at 1, 2, 5 (or 1, 3) x 10^k, labelled as plain numbers, no minor
    labels (matplotlib labels every minor tick of a narrow log range, and they overlap)."""
    axis.set_major_locator(ticker.LogLocator(base=10, subs=subs))
    axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:.3g}"))
    axis.set_minor_locator(ticker.NullLocator())


def plot_posterior(post, var_names: Sequence[str] | None = None,
                   path: str | os.PathLike | None = None, dpi: float = 80) -> Figure:
    """The rows described in the module docstring; written to ``path`` if given.

    Args:
        post: a :class:`~bayesmotion.inference.posterior.Posterior`.
        var_names: variables to show (default: the hyperparameters gamma, beta, alpha and,
            with stable dynamics, the AR coefficients).
        path: a PNG (or any format matplotlib writes) to save, atomically.
        dpi: resolution when saving.
    Returns:
        the figure (no pyplot: display ``fig`` in a notebook).
    """
    rows = coordinate_table(post, var_names)
    fig = Figure(figsize=(10.0, 1.45 * len(rows) + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(rows), 2, squeeze=False, width_ratios=(3, 1))
    for (ax_t, ax_h), row in zip(axes, rows, strict=True):
        x = row["draws"]
        for c in x[:MAX_CHAINS_DRAWN]:
            ax_t.plot(c, lw=0.5, alpha=0.5)
        flat = x.ravel()
        if row["log"] and np.all(flat > 0):
            ax_t.set_yscale("log")
            ax_h.set_xscale("log")
            _plain_log_ticks(ax_t.yaxis, (1, 2, 5))
            _plain_log_ticks(ax_h.xaxis, (1, 3))
            lo, hi = flat.min(), flat.max()
            bins = np.geomspace(lo, hi, 40) if hi > lo else 10
        else:
            bins = 40
        ax_h.hist(flat, bins=bins, color="0.4")
        ax_h.set_yticks([])
        ax_t.set_ylabel(row["name"], rotation=0, ha="right", va="center", fontsize=9)
        ok = row["rhat"] <= RHAT_OK
        ax_t.set_title(f"R-hat {row['rhat']:.3f}   ESS bulk {row['ess_bulk']:.0f} / tail "
                       f"{row['ess_tail']:.0f}", fontsize=8, loc="right", pad=2,
                       color="black" if ok else "tab:red")
        ax_t.tick_params(labelsize=8)
        ax_h.tick_params(labelsize=8)
    axes[-1, 0].set_xlabel("draw (after burn-in and thinning)")
    axes[-1, 1].set_xlabel("value")
    fig.suptitle(f"posterior ({post.method}, {x.shape[0]} chains x {x.shape[1]} draws); "
                 "log axes for scales", fontsize=10)
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig
