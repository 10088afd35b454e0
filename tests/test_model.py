"""The hierarchy: log-posterior assembly, MAP fit, jitter handling, model files."""

import io
import json
import zipfile
from importlib.resources import files

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

import bayesmotion as bm
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.model.io import load
from bayesmotion.model.logpost import LogPosterior
from bayesmotion.model.spec import HGPDM
from bayesmotion.optim.minimize import JITTER_LADDER, map_optimize


def tiny_dataset(n_trials=4, frames=12, fps=15):
    """Segments of the shipped real CMU handshake with two planted labels (test-sized)."""
    root = files("bayesmotion") / "datasets" / "builtin"
    a = bm.read_bvh(root / "18_01.bvh").select(slice(1, None)).resample(fps)
    b = bm.read_bvh(root / "19_01.bvh").select(slice(1, None)).resample(fps)
    trials = []
    for k in range(n_trials):
        sl = slice(k * 5, k * 5 + frames)
        trials.append(bm.Trial((a.select(sl), b.select(sl)),
                               {"emotion": ("happy", "sad")[k % 2], "couple": "c1"}, f"t{k}"))
    return bm.MotionDataset(trials)


@pytest.fixture(scope="module")
def fitted():
    return HGPDM(latent_dim=3, interaction_dim=3).fit(tiny_dataset(), max_iter=60,
                                                      progress=False)


@pytest.mark.slow
def test_log_posterior_is_sum_of_layers_and_blocked_equals_dense(fitted):
    lp = fitted.log_posterior_fn
    p = fitted.to_device()
    terms = lp.layer_terms(p, 1e-8)
    assert float(lp(p, 1e-8)) == pytest.approx(sum(float(v) for v in terms.values()), rel=1e-12)
    dense = LogPosterior(fitted.spec, fitted.data, dense=True)
    # at every rung of the jitter ladder: the blocked path adds the dense path's jitter (relative
    # to the mean diagonal over the real rows) and leaves its padding rows untouched (jitter on
    # the padding rows would differ by 0.13 nats per layer at jitter 1e-2)
    for j in (0.0, *JITTER_LADDER):
        np.testing.assert_allclose(float(dense(p, j)), float(lp(p, j)), rtol=1e-10, err_msg=j)
    g_dense = jax.grad(lambda q: dense(q, 1e-4))(p)
    g_block = jax.grad(lambda q: lp(q, 1e-4))(p)
    for k in g_dense:
        np.testing.assert_allclose(np.asarray(g_block[k]), np.asarray(g_dense[k]), rtol=1e-6,
                                   atol=1e-6 * float(np.max(np.abs(g_dense[k]))), err_msg=k)
    np.testing.assert_allclose(float(jax.jit(lp)(p, 1e-8)), float(lp(p, 1e-8)), rtol=1e-9)


def test_log_posterior_gradient_matches_finite_differences(fitted):
    """At the (well-conditioned) initial point, with free style vectors included."""
    from bayesmotion.model.fit import init_params
    from bayesmotion.model.params import simplex_to_style

    lp = fitted.log_posterior_fn
    p0 = init_params(fitted.spec, fitted.data)
    p0["style:emotion"] = np.asarray(simplex_to_style(np.array([[0.7, 0.3], [0.2, 0.8]])))
    x0, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in p0.items()})
    f = jax.jit(lambda x: lp(unravel(x), 1e-8))
    g = np.asarray(jax.grad(f)(x0))
    rng = np.random.default_rng(0)
    for _ in range(5):
        v = rng.normal(size=x0.size)
        v /= np.linalg.norm(v)
        h = 1e-5
        fd = (float(f(x0 + h * v)) - float(f(x0 - h * v))) / (2 * h)
        assert fd == pytest.approx(g @ v, rel=1e-4, abs=1e-4)


def test_fit_decreases_objective_and_records_diagnostics(fitted):
    d = fitted.diagnostics
    assert d["objective"] < d["initial_objective"]
    trace = np.array(d["trace"])
    assert np.all(np.diff(trace) <= 1e-8 * np.abs(trace[:-1]))  # L-BFGS accepts only descents
    assert 1 <= d["iterations"] <= 60 and d["evaluations"] >= d["iterations"]
    assert len(trace) == d["iterations"]  # one objective per L-BFGS iteration
    assert trace[-1] == pytest.approx(d["objective"], rel=1e-10, abs=1e-6)
    assert np.isfinite(d["grad_norm"]) and d["grad_norm"] > 0
    assert d["jitter"] in JITTER_LADDER and d["jitter_events"] == []
    c = d["convergence"]
    assert d["converged"] == c["met"] and isinstance(d["converged"], bool)
    # stopped by its limit or converged, and the message says which
    assert c["max_iter_reached"] == (d["iterations"] >= 60 and not d["converged"])
    assert ("LIMIT" in d["message"]) == c["max_iter_reached"]
    assert np.isfinite(fitted.log_posterior())


def test_fit_is_deterministic_for_a_seed():
    ds = tiny_dataset(n_trials=2)
    spec = HGPDM(latent_dim=2, interaction_dim=2)
    a = spec.fit(ds, max_iter=10, progress=False, seed=3)
    b = spec.fit(ds, max_iter=10, progress=False, seed=3)
    c = spec.fit(ds, max_iter=10, progress=False, seed=4)
    np.testing.assert_array_equal(a.params["I"], b.params["I"])
    assert not np.array_equal(a.params["I"], c.params["I"])


def test_optimized_style_vectors_stay_on_the_simplex():
    m = HGPDM(latent_dim=2, interaction_dim=2).fit(tiny_dataset(n_trials=4), max_iter=15,
                                                   optimize_style=True, progress=False)
    s = m.styles()["emotion"]
    np.testing.assert_allclose(s.sum(1), 1.0, rtol=1e-12)
    assert np.all(s > 0)
    # each trial's style stays closest to its own label
    assert list(np.argmax(s, 1)) == [0, 1, 0, 1]  # levels sorted: happy, sad


def test_style_vectors_can_be_freed_per_factor():
    ds = tiny_dataset(n_trials=4)
    spec = HGPDM(latent_dim=2, interaction_dim=2)
    m = spec.fit(ds, max_iter=40, optimize_style=("emotion",), progress=False)
    assert [k for k in m.params if k.startswith("style:")] == ["style:emotion"]
    # a warm start keeps the style vectors it brings instead of resetting them to the prior
    # mean (one L-BFGS step moves them a little either way)
    again = spec.fit(ds, max_iter=0, optimize_style=("emotion",), progress=False,
                     init={"style:emotion": m.params["style:emotion"]})
    fresh = spec.fit(ds, max_iter=0, optimize_style=("emotion",), progress=False)
    gap = lambda f: np.max(np.abs(np.asarray(f.params["style:emotion"])
                                  - np.asarray(m.params["style:emotion"])))
    assert gap(again) < 0.1 * gap(fresh)
    with pytest.raises(bm.BayesmotionError, match="content"):
        spec.fit(ds, max_iter=5, optimize_style=("content",), progress=False)


def test_escalating_jitter_is_used_and_reported():
    """A density that fails (-inf) below jitter 1e-4 still gets optimised, and it is reported."""
    def logp(p, jitter):
        val = -jnp.sum((p["x"] - 2.0) ** 2)
        return jnp.where(jitter >= 1e-4, val, -jnp.inf)

    params, diag = map_optimize(logp, {"x": np.zeros(3)}, progress=False)
    np.testing.assert_allclose(params["x"], 2.0, atol=1e-5)
    assert [e["jitter"] for e in diag["jitter_events"]] == [1e-6, 1e-4]
    assert diag["jitter"] == 1e-4


def test_save_load_round_trip_is_bit_exact(fitted, tmp_path):
    path = tmp_path / "model.npz"
    fitted.save(path)
    back = load(path)
    assert back.log_posterior() == fitted.log_posterior()
    for k, v in fitted.params.items():
        np.testing.assert_array_equal(back.params[k], v)
    assert back.spec == fitted.spec
    assert back.levels == {k: tuple(v) for k, v in fitted.levels.items()}
    assert [t.labels for t in back.trials] == [t.labels for t in fitted.trials]
    np.testing.assert_array_equal(back.codecs[1].scale, fitted.codecs[1].scale)


def test_save_is_atomic_and_keeps_old_file_on_failure(fitted, tmp_path, monkeypatch):
    path = tmp_path / "model.npz"
    fitted.save(path)
    before = path.read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr("os.replace", boom)
    with pytest.raises(OSError):
        fitted.save(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["model.npz"]


def test_corrupted_and_foreign_files_raise_model_file_error(fitted, tmp_path):
    good = tmp_path / "good.npz"
    fitted.save(good)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:500])
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, a=np.arange(3))
    text = tmp_path / "text.npz"
    text.write_text("hello")
    wrong_meta = tmp_path / "meta.npz"
    np.savez(wrong_meta, __meta__=np.frombuffer(json.dumps({"format": "x"}).encode(), np.uint8))
    missing = tmp_path / "missing.npz"
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(missing, "w") as zout:
        for item in zin.infolist():
            if not item.filename.startswith("param/I"):
                zout.writestr(item, zin.read(item.filename))
    for bad in (truncated, foreign, text, wrong_meta, missing, tmp_path / "absent.npz"):
        with pytest.raises(ModelFileError):
            load(bad)


def test_pickled_object_arrays_are_refused_without_running_them(fitted, tmp_path):
    """A valid model file plus one pickled entry: loading must refuse it, and the pickle's
    payload must not run (the marker file stays absent). Were the archive read with
    ``allow_pickle=True``, the payload would run while the entry is read."""
    marker = tmp_path / "payload_ran"
    good = tmp_path / "good.npz"
    fitted.save(good)
    evil = tmp_path / "evil.npz"
    payload = np.array([_Payload(str(marker))], dtype=object)
    buf = io.BytesIO()
    np.save(buf, payload, allow_pickle=True)
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(evil, "w") as zout:
        for item in zin.infolist():
            zout.writestr(item, zin.read(item.filename))
        zout.writestr("param/evil.npy", buf.getvalue())
    with pytest.raises(ModelFileError):
        load(evil)
    assert not marker.exists()
    # the check above can fail: the same archive read with pickles allowed runs the payload
    with np.load(evil, allow_pickle=True) as z:
        z["param/evil"]
    assert marker.exists()


class _Payload:
    def __init__(self, path):
        self.path = path

    def __reduce__(self):  # unpickling creates a directory at ``path``
        import os

        return (os.mkdir, (self.path,))


def _rewrite(src, dst, change):
    """Copy a model archive, replacing entry name -> change(name, array) (None drops it)."""
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    out = {}
    for k, v in arrays.items():
        v = change(k, v)
        if v is not None:
            out[k] = v
    np.savez(dst, **out)
    return dst


def _with_meta(src, dst, edit):
    def change(k, v):
        if k != "__meta__":
            return v
        meta = json.loads(v.tobytes().decode())
        edit(meta)
        return np.frombuffer(json.dumps(meta).encode(), np.uint8)
    return _rewrite(src, dst, change)


def test_every_corrupted_byte_of_a_model_file_raises_model_file_error(fitted, tmp_path):
    """Flipping bytes inside the compressed entries (zlib errors, bad CRCs, garbage arrays)
    gives a ModelFileError, never another exception."""
    good = tmp_path / "good.npz"
    fitted.save(good)
    raw = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as z:
        entries = [(i.header_offset + 30 + len(i.filename), i.compress_size)
                   for i in z.infolist()]
    rng = np.random.default_rng(0)
    n = 0
    for start, size in entries:
        for pos in rng.integers(start, start + max(size, 1), size=4):
            bad = bytearray(raw)
            bad[pos] ^= 0xFF
            path = tmp_path / "bad.npz"
            path.write_bytes(bytes(bad))
            try:
                load(path)
            except ModelFileError:
                n += 1
            except Exception as e:  # noqa: BLE001 -- what the test is about
                pytest.fail(f"byte {pos}: {type(e).__name__}: {e}")
            # else: a flip that the CRC misses and that still decodes; allowed, if rare
    assert n > 0.9 * 4 * len(entries)


@pytest.mark.parametrize("case", ["X_1d", "no_gamma", "alpha_3", "levels_vs_onehot",
                                  "nan_param", "extra_param", "lengths"])
def test_inconsistent_model_files_are_refused_at_load(fitted, tmp_path, case):
    good = tmp_path / "good.npz"
    fitted.save(good)
    dst = tmp_path / f"{case}.npz"
    if case == "X_1d":
        _rewrite(good, dst, lambda k, v: v.ravel() if k == "param/X" else v)
    elif case == "no_gamma":
        _with_meta(good, dst, lambda m: m["params"].remove("log_gamma"))
    elif case == "alpha_3":
        _rewrite(good, dst, lambda k, v: v[:3] if k == "param/log_alpha" else v)
    elif case == "levels_vs_onehot":
        _with_meta(good, dst, lambda m: m["levels"]["emotion"].append("bored"))
    elif case == "nan_param":
        _rewrite(good, dst, lambda k, v: v * np.nan if k == "param/log_beta" else v)
    elif case == "extra_param":
        def extra(k, v):
            return v
        _rewrite(good, dst, extra)
        _with_meta(dst, dst, lambda m: m["params"].append("lengths"))
    elif case == "lengths":
        _rewrite(good, dst, lambda k, v: v[::-1] + np.array([1] + [0] * (v.size - 1))
                 if k == "lengths" else v)
    with pytest.raises(ModelFileError):
        load(dst)


def test_saved_files_get_the_usual_permissions(fitted, tmp_path):
    """Model and netCDF files are created 0o666 & ~umask, like any file, and keep the mode of a
    file they replace (a temporary file's private 0o600 must not leak)."""
    import os

    umask = os.umask(0o022)
    try:
        path = tmp_path / "model.npz"
        fitted.save(path)
        assert path.stat().st_mode & 0o777 == 0o644
        path.chmod(0o640)
        fitted.save(path)
        assert path.stat().st_mode & 0o777 == 0o640
    finally:
        os.umask(umask)


def test_an_objective_that_is_never_finite_raises_instead_of_converging():
    """With no finite evaluation the optimiser must say what failed, not stop at once and
    report converged=True at the start point."""
    logp = lambda p, j: jnp.sum(p["a"]) - jnp.inf  # noqa: E731
    with pytest.raises(bm.BayesmotionError, match="not finite at any point"):
        map_optimize(logp, {"a": np.zeros(3)}, max_iter=5, progress=False)


@pytest.mark.parametrize("bad", [{"init_var": 0.0}, {"log_scale": -1.0}, {"gamma_loc": (1, 1)},
                                 {"beta_loc": (1.0, 0.0, 1.0)}, {"alpha_noise": float("nan")},
                                 {"style_kappa": -1.0}, {"style_kappa": "ten"}])
def test_invalid_priors_are_refused_by_name(bad):
    from bayesmotion.model.params import Priors

    with pytest.raises(bm.BayesmotionError, match=f"Priors.{next(iter(bad))}"):
        Priors(**bad)


def test_shared_latent_init_puts_every_style_cell_in_one_region(fitted):
    """fit(init="shared"): I starts from the stacked X with each interaction cell's mean
    removed, so every cell's latents are centred on one point (PCA's keep their cells apart);
    X is PCA's either way; an unknown name or type is refused before any work."""
    from bayesmotion.gp.densities import cell_ids
    from bayesmotion.model.fit import init_params

    spec, data = fitted.spec, fitted.data
    cells = cell_ids([data.onehot[f][data.trial_of_frame] for f in spec.interaction_factors])
    assert cells.max() >= 1  # at least two cells to compare

    def cell_means(I):
        return np.stack([I[cells == c].mean(0) for c in range(cells.max() + 1)])

    pca_p = init_params(spec, data, 0)
    shared = init_params(spec, data, 0, latents="shared")
    np.testing.assert_array_equal(pca_p["X"], shared["X"])
    spread = np.abs(cell_means(pca_p["I"])).max()
    assert spread > 0.1  # PCA's cells start apart (the first component has unit sd)
    # shared: only the 1e-3 tie-breaking jitter is left of the cell means
    assert np.abs(cell_means(shared["I"])).max() < 0.02 * spread
    assert shared["I"][:, 0].std() > 0.5  # the within-cell variation is kept, not collapsed
    tiny = tiny_dataset()
    model = HGPDM(latent_dim=3, interaction_dim=3).fit(tiny, max_iter=5, progress=False,
                                                       init="shared")
    assert np.all(np.isfinite(model.params["I"]))
    for bad, match in (("random", "one of"), (3, "parameter dict")):
        with pytest.raises(BayesmotionError, match=match):
            HGPDM(latent_dim=3, interaction_dim=3).fit(tiny, max_iter=5, progress=False,
                                                       init=bad)
