"""arviz conversion, netCDF files and comparison of two posteriors (emcee vs NUTS)."""

from __future__ import annotations

import contextlib
import warnings

import numpy as np

from bayesmotion.data.files import atomic_path
from bayesmotion.inference.target import chain_gram

_ARVIZ_NOTICE = r"\s*ArviZ is undergoing a major refactor"


def import_arviz():
    """Import arviz and return it, safe when several processes import it at once.

    arviz 0.2x writes a once-a-day stamp file (under the user's cache folder) on import through
    one fixed temporary name, so two processes importing it for the first time that day (two
    test workers, two jobs of a batch) can race: one renames the other's temporary file away and
    the import fails with ``FileNotFoundError``. The stamp is written by then, so importing again
    succeeds; that one retry is all this adds. The import's notice of arviz 1.0 is not shown:
    bayesmotion requires arviz < 1.0, so the announced changes do not reach its users.
    """
    import sys

    for attempt in range(2):
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=_ARVIZ_NOTICE, category=FutureWarning)
                warnings.filterwarnings("ignore", message=_ARVIZ_NOTICE, category=UserWarning)
                import arviz
            return arviz
        except FileNotFoundError as err:
            if attempt or "daily_warning" not in str(err):
                raise
            for name in [m for m in sys.modules if m == "arviz" or m.startswith("arviz.")]:
                del sys.modules[name]
    raise AssertionError("unreachable")


def _dims(model) -> tuple[dict, dict]:
    o = model.spec.order
    coords = {
        "gamma_dim": ["gamma1_signal", "gamma2_inv_ls", "gamma3_noise_prec"],
        "beta_dim": ["beta1_signal", "beta2_inv_ls", "beta3_noise_prec"],
        "alpha_dim": (["alpha_rbf"] + [f"alpha_ls_lag{l + 1}" for l in range(o)]
                      + ([] if model.spec.stable_dynamics
                         else [f"alpha_lin_lag{l + 1}" for l in range(o)])
                      + ["alpha_noise_prec"]),
    }
    dims = {"gamma": ["gamma_dim"], "beta": ["beta_dim"], "alpha": ["alpha_dim"]}
    if model.spec.stable_dynamics:
        coords["ar_lag"] = [f"a_lag{l + 1}" for l in range(o)]
        dims["ar"] = ["ar_lag"]
    for f in model.spec.factors:
        coords[f"{f}_level"] = list(model.levels[f])
        coords[f"{f}_label"] = list(model.levels[f])
        dims[f"style_{f}"] = [f"{f}_label", f"{f}_level"]  # vector of each label, coordinates
    return coords, dims


def to_inference_data(post):
    """arviz InferenceData: posterior (chain = walker for emcee), sample_stats (lp,
    acceptance), observed_data (training poses per actor)."""
    az = import_arviz()

    coords, dims = _dims(post.model)
    C, D = post.chains.shape[:2]
    acc = np.broadcast_to(np.asarray(post.acceptance)[:, None], (C, D))
    observed = {f"Y_actor{a}": np.asarray(Y) for a, Y in enumerate(post.model.data.Y)}
    for a in range(len(post.model.data.Y)):
        dims[f"Y_actor{a}"] = ["frame", f"pose_dim_actor{a}"]
    with warnings.catch_warnings():
        # emcee runs many walkers (chains) of few draws; arviz warns about that shape
        warnings.filterwarnings("ignore", message="More chains")
        idata = _from_dict(az, post, coords, dims, acc, observed)
    return idata


def _from_dict(az, post, coords, dims, acc, observed):
    return az.from_dict(
        posterior=post.constrained(),
        sample_stats={"lp": post.log_prob, "acceptance_rate": acc},
        observed_data=observed,
        coords=coords,
        dims=dims,
        attrs={"sampler": post.method, "inference_library": "bayesmotion",
               "burn": int(post.info.get("burn", 0)), "thin": int(post.info.get("thin", 1))},
    )


def save_netcdf(idata, path) -> str:
    """Write InferenceData to netCDF atomically (temp file, then rename)."""
    with atomic_path(path) as tmp:  # usual permissions, removed on failure
        idata.to_netcdf(str(tmp), engine="h5netcdf")
    return str(path)


def _theta(x):
    """arviz Dataset of (chains, draws, ndim) draws; emcee has more walkers than draws, a shape
    arviz warns about, so that one warning is silenced here."""
    az = import_arviz()

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="More chains")
        return az.convert_to_dataset({"theta": np.asarray(x)})


@contextlib.contextmanager
def arviz_without_numba():
    """Run arviz diagnostics on its NumPy path. With numba installed, arviz 0.2x's numba path
    of ``mcse(method="sd")`` (also inside ``az.summary``) fails under numpy >= 2.5: "only
    0-dimensional arrays can be converted to Python scalars" (seen with arviz 0.23.4, numpy
    2.5.2, numba installed). The flag is restored afterwards."""
    import_arviz()
    from arviz.utils import Numba

    was = Numba.numba_flag
    Numba.numba_flag = False
    try:
        yield
    finally:
        Numba.numba_flag = was


def compare_posteriors(a, b, var_names=None) -> dict:
    """Compare two posteriors of the same target (e.g. emcee vs NUTS).

    For every unconstrained coordinate and style Gram entry (:func:`with_gram`): both means and
    both standard deviations, their Monte-Carlo standard errors (arviz ``mcse``, methods "mean"
    and "sd"), the z-scores of the differences, and the R-hat of the pooled chains of both
    methods (draws truncated to the shorter run).

    Returns:
        dict with per-coordinate arrays and ``max_abs_z``, ``max_abs_z_sd``, ``max_rhat``.
    """
    az = import_arviz()

    ca, names = with_gram(a)
    cb, _ = with_gram(b)

    def ds(x):
        return _theta(x), x

    n = min(ca.shape[1], cb.shape[1])
    da, xa = ds(ca)
    db, xb = ds(cb)
    mean_a, mean_b = xa.mean((0, 1)), xb.mean((0, 1))
    with arviz_without_numba():
        se_a, se_b = (az.mcse(d)["theta"].values for d in (da, db))
        sse_a, sse_b = (az.mcse(d, method="sd")["theta"].values for d in (da, db))
    z = (mean_a - mean_b) / np.sqrt(se_a**2 + se_b**2)
    sd_a, sd_b = xa.std((0, 1)), xb.std((0, 1))
    z_sd = (sd_a - sd_b) / np.sqrt(sse_a**2 + sse_b**2)
    pooled = np.concatenate([ca[:, -n:], cb[:, -n:]])
    rhat = az.rhat(_theta(pooled))["theta"].values
    return {"names": names, "mean_a": mean_a, "mean_b": mean_b, "mcse_a": se_a,
            "mcse_b": se_b, "z": z, "sd_a": sd_a, "sd_b": sd_b, "mcse_sd_a": sse_a,
            "mcse_sd_b": sse_b, "z_sd": z_sd, "rhat": rhat,
            "max_abs_z": float(np.max(np.abs(z))), "max_abs_z_sd": float(np.max(np.abs(z_sd))),
            "max_rhat": float(np.max(rhat))}


def with_gram(post) -> tuple[np.ndarray, list[str]]:
    """(chains (n_chains, n_draws, ndim + m), names): the posterior's unconstrained draws and,
    after them, its style vectors' Gram entries (:func:`bayesmotion.inference.target.gram_entries`,
    none for a target without style vectors)."""
    x = np.asarray(post.chains)
    target = getattr(post, "target", None)
    names = list(getattr(target, "names", range(x.shape[-1])))
    if hasattr(target, "unravel"):
        gram_names, g = chain_gram(target, x)
        x, names = np.concatenate([x, g], -1), names + gram_names
    return x, names


def convergence(post) -> dict:
    """max R-hat, min bulk and tail ESS over all sampled coordinates (unconstrained) and the
    style vectors' Gram entries (:func:`bayesmotion.inference.target.gram_entries`, what
    the likelihood identifies of them; the style rotations leave them unchanged, so the
    vectors' own coordinates can look mixed while these are not)."""
    az = import_arviz()

    d = _theta(with_gram(post)[0])
    with arviz_without_numba():
        return {"max_rhat": float(az.rhat(d)["theta"].max()),
                "min_ess_bulk": float(az.ess(d, method="bulk")["theta"].min()),
                "min_ess_tail": float(az.ess(d, method="tail")["theta"].min()),
                "mean_acceptance": float(np.mean(post.acceptance))}
