"""The sparse H-GPDM (``HGPDM(inducing=M)``) against the exact one: cost in N, a large fit, and
accuracy on the built-in handshakes.

    python benchmarks/sparse_scaling.py [--quick] [--part scaling|large_fit|handshakes]

Parts (each can be run alone with ``--part``; the JSON keeps the other parts' last results):

* ``scaling``: one jitted value + gradient of the log-posterior (as the MAP fit calls it) on
  the 40 shared Bandai clips resampled to 60 fps (12,682 frames; one actor, emotion factor),
  first the clips' first n frames for growing N, sparse at fixed M and exact (block-diagonal
  by emotion, its fastest path) side by side up to the size the exact model manages. The
  exponent k of time ~ N^k is the least-squares slope on log-log.
* ``large_fit``: the sparse MAP fit of all 12,682 frames (``max_iter`` iterations or
  ``max_seconds``), whole wall time including compilation, and a 300-frame rollout.
* ``handshakes``: leave-one-trial-out on the built-in handshakes at 10 fps (24 trials, N = 408)
  for the exact model and the sparse one, the same folds and settings: each fold refitted
  without the trial (warm-started from the model fitted on all trials), the held-out trial's
  emotion inferred (couple given), and its reconstruction error: the RMS, over frames and pose
  channels of the model's (standardised) pose space, of the held-out poses minus the bottom
  layer's predictive mean at the trial's projected latents (``EmotionPosterior.latents``).

Without the Bandai clips (``../shared/data/bandai-emotion``) the Bandai parts record that
they were skipped. The JSON is written atomically to ``results/sparse_scaling.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import BANDAI_ROOT, RESULTS, bandai_present, headline  # noqa: E402

NAME = "sparse_scaling"
FULL = {"M": 256, "sizes": [1500, 3000, 6000, 12682], "exact_max_n": 3000, "fps": 60.0,
        "max_iter": 1000, "max_seconds": 1800, "hs_M": 100, "hs_fit_iter": 300,
        "hs_refit_iter": 50, "hs_n_steps": 100, "hs_projection_iter": 300}
QUICK = {"M": 64, "sizes": [400, 800], "exact_max_n": 800, "fps": 10.0,
         "max_iter": 20, "max_seconds": 120, "hs_M": 40, "hs_fit_iter": 20,
         "hs_refit_iter": 5, "hs_n_steps": 20, "hs_projection_iter": 30, "hs_couples": ["c1"],
         "hs_trials": 4}
PARTS = ("scaling", "large_fit", "handshakes")


def loglog_slope(n, t) -> float:
    return float(np.polyfit(np.log(n), np.log(t), 1)[0])


def _bandai(fps):
    import bayesmotion as bm

    return bm.load_bandai(BANDAI_ROOT, fps=fps)


def _first_frames(ds, n: int):
    """The dataset's clips in order, the last one cut, so that they hold n frames in all."""
    import bayesmotion as bm

    trials, total = [], 0
    for t in ds.trials:
        k = t.n_frames
        if total + k > n:
            k = n - total
            if k < 10:
                break
            t = bm.Trial(tuple(m.select(slice(0, k)) for m in t.actors), t.labels, t.name)
        trials.append(t)
        total += k
        if total >= n:
            break
    return bm.MotionDataset(tuple(trials), ds.levels, name=ds.name)


def _value_and_grad(spec, ds):
    import jax
    import jax.numpy as jnp
    from jax.flatten_util import ravel_pytree

    from bayesmotion.model.data import fit_codecs, prepare_data
    from bayesmotion.model.fit import init_params
    from bayesmotion.model.logpost import LogPosterior

    spec = spec.resolved(ds)
    data = prepare_data(spec, ds, fit_codecs(spec, ds))
    logp = LogPosterior(spec, data)
    x0, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in init_params(spec, data).items()})
    return jax.jit(jax.value_and_grad(lambda x, j: -logp(unravel(x), j))), x0, data


def part_scaling(s: dict) -> dict:
    from _common import block, timeit

    from bayesmotion import HGPDM

    if not bandai_present(BANDAI_ROOT):
        return {"skipped": f"no Bandai clips at {BANDAI_ROOT}"}
    ds = _bandai(s["fps"])
    rows = []
    for n in s["sizes"]:
        sub = _first_frames(ds, n)
        for kind, spec in (("sparse", HGPDM(inducing=s["M"])), ("exact", HGPDM())):
            if kind == "exact" and n > s["exact_max_n"]:
                continue
            vg, x0, data = _value_and_grad(spec, sub)
            t0 = time.perf_counter()
            block(vg(x0, 1e-8))
            first = time.perf_counter() - t0
            t = timeit(lambda vg=vg, x0=x0: block(vg(x0, 1e-8)), repeats=3, warmup=1)
            rows.append({"N": int(data.lengths.sum()), "kind": kind, "M": s["M"]
                         if kind == "sparse" else None, "trials": len(sub),
                         "first_call_s_incl_compile": first, **t})
    sp = [r for r in rows if r["kind"] == "sparse"]
    ex = [r for r in rows if r["kind"] == "exact"]
    out = {"measurements": rows,
           "exponent_sparse": loglog_slope([r["N"] for r in sp], [r["median_s"] for r in sp]),
           "exponent_exact": (loglog_slope([r["N"] for r in ex], [r["median_s"] for r in ex])
                              if len(ex) > 1 else None)}
    if len(sp) > 2:
        out["exponent_sparse_two_largest"] = loglog_slope([r["N"] for r in sp[-2:]],
                                                          [r["median_s"] for r in sp[-2:]])
    return out


def part_large_fit(s: dict) -> dict:
    from bayesmotion import HGPDM

    if not bandai_present(BANDAI_ROOT):
        return {"skipped": f"no Bandai clips at {BANDAI_ROOT}"}
    ds = _bandai(s["fps"])
    t0 = time.perf_counter()
    model = HGPDM(inducing=s["M"]).fit(ds, max_iter=s["max_iter"],
                                       max_seconds=s["max_seconds"], progress=False)
    fit_s = time.perf_counter() - t0
    d = model.diagnostics
    t0 = time.perf_counter()
    r = model.generate(emotion="happy", n_frames=300, seed=0)
    gen_s = time.perf_counter() - t0
    return {"N": int(model.data.lengths.sum()), "trials": len(ds), "M": s["M"],
            "fit_wall_s": fit_s, "iterations": d.get("iterations"),
            "objective": d.get("objective"),
            "convergence": d.get("convergence"),
            "rollout_300_frames_s": gen_s,
            "rollout_finite": bool(np.all(np.isfinite(r.positions))),
            "rollout_latent_range_vs_training": float(
                np.max(np.abs(r.I)) / np.max(np.abs(np.asarray(model.params["I"]))))}


def _reconstruction_rms(model, clip, ep) -> float:
    import jax.numpy as jnp

    from bayesmotion.emotion.clip import clip_poses
    from bayesmotion.model.predict import predict_bottom_mean

    P = model.predictor()
    Ys = clip_poses(model, clip)
    X = np.asarray(ep.latents["X"])
    err = [np.asarray(predict_bottom_mean(P, a, jnp.asarray(X[a]))) - Y
           for a, Y in enumerate(Ys)]
    return float(np.sqrt(np.mean(np.concatenate([e.ravel() for e in err]) ** 2)))


def part_handshakes(s: dict) -> dict:
    import bayesmotion as bm
    from bayesmotion.evaluation.evaluate import _fold_init

    ds = bm.load_handshakes(fps=10.0)
    if s.get("hs_couples"):
        ds = ds.filter(couple=s["hs_couples"])
    n_folds = s.get("hs_trials", len(ds))
    out = {}
    for kind, spec in (("exact", bm.HGPDM()), ("sparse", bm.HGPDM(inducing=s["hs_M"]))):
        t0 = time.perf_counter()
        full = spec.fit(ds, max_iter=s["hs_fit_iter"], progress=False)
        rows = []
        for i, (train, held) in enumerate(ds.leave_one_out()):
            if i >= n_folds:
                break
            keep = [r for r in range(len(ds)) if r != i]
            fold = spec.fit(train, max_iter=s["hs_refit_iter"], progress=False,
                            init=_fold_init(full, keep))
            ep = bm.infer_emotion(fold, held, styles={"couple": held.labels["couple"]},
                                  n_steps=s["hs_n_steps"], seed=i, latent_uncertainty=False,
                                  max_iter=s["hs_projection_iter"])
            rows.append({"trial": held.name, "true": held.labels["emotion"],
                         "pred": ep.label, "p_true": float(ep.probabilities[
                             ep.levels.index(held.labels["emotion"])]),
                         "reconstruction_rms": _reconstruction_rms(fold, held, ep),
                         "seconds": float(ep.info["seconds"])})
        out[kind] = {"N": int(full.data.lengths.sum()), "M": spec.inducing,
                     "accuracy": float(np.mean([r["true"] == r["pred"] for r in rows])),
                     "reconstruction_rms": float(np.mean([r["reconstruction_rms"]
                                                          for r in rows])),
                     "wall_s": time.perf_counter() - t0, "folds": rows}
    e, p = out["exact"], out["sparse"]
    out["accuracy_points_lost"] = 100 * (e["accuracy"] - p["accuracy"])
    out["reconstruction_rms_ratio"] = p["reconstruction_rms"] / e["reconstruction_rms"]
    return out


RUNNERS = {"scaling": part_scaling, "large_fit": part_large_fit, "handshakes": part_handshakes}


def _headline(res: dict, quick: bool) -> list[dict]:
    rows = []
    sc = res.get("scaling", {})
    if "exponent_sparse" in sc:
        big = max((r for r in sc["measurements"] if r["kind"] == "sparse"),
                  key=lambda r: r["N"])
        two = sc.get("exponent_sparse_two_largest")
        rows.append(headline(f"sparse value+grad cost exponent in N (M = {big['M']})",
                             sc["exponent_sparse"], "", "<= 1.2",
                             None if quick else sc["exponent_sparse"] <= 1.2,
                             f"{big['median_s']:.2f} s at N = {big['N']}"
                             + (f"; two largest sizes {two:.2f}" if two is not None else "")
                             + (f"; exact: exponent {sc['exponent_exact']:.2f}"
                                if sc.get("exponent_exact") is not None else "")))
    lf = res.get("large_fit", {})
    if "fit_wall_s" in lf:
        rows.append(headline(f"sparse fit of N = {lf['N']} frames (M = {lf['M']})",
                             lf["fit_wall_s"] / 60, "min", "< 30",
                             None if quick else lf["fit_wall_s"] < 1800,
                             f"{lf['iterations']} iterations; converged: "
                             f"{(lf['convergence'] or {}).get('met')}; 300-frame rollout "
                             f"finite: {lf['rollout_finite']}"))
    hs = res.get("handshakes", {})
    if "exact" in hs:
        rows.append(headline("handshakes LOO: sparse accuracy points lost vs exact",
                             hs["accuracy_points_lost"], "points", "<= 5",
                             None if quick else hs["accuracy_points_lost"] <= 5,
                             f"exact {100 * hs['exact']['accuracy']:.0f}%, sparse "
                             f"{100 * hs['sparse']['accuracy']:.0f}% (M = "
                             f"{hs['sparse']['M']} of N = {hs['sparse']['N']})"))
        rows.append(headline("  held-out reconstruction error, sparse / exact",
                             hs["reconstruction_rms_ratio"], "x", "<= 1.05",
                             None if quick else hs["reconstruction_rms_ratio"] <= 1.05,
                             f"RMS {hs['sparse']['reconstruction_rms']:.3f} vs "
                             f"{hs['exact']['reconstruction_rms']:.3f}"))
    return rows


def run(quick: bool, parts=PARTS, previous: dict | None = None) -> dict:
    s = QUICK if quick else FULL
    res = {k: v for k, v in (previous or {}).items() if k in PARTS}
    for name in parts:
        res[name] = RUNNERS[name](s)
    return {"settings": {**s, "quick": quick}, **res, "headline": _headline(res, quick)}


def main() -> int:
    from _common import machine_info, write_json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, a few folds")
    ap.add_argument("--part", choices=PARTS, action="append",
                    help="run only these parts (repeatable); the others keep their results")
    a = ap.parse_args()
    import bayesmotion  # noqa: F401  (float64 on)

    path = RESULTS / f"{NAME}.json"
    mode = "quick" if a.quick else "full"
    previous = None
    if a.part and path.exists():
        old = json.loads(path.read_text())
        previous = old if old.get("mode") == mode else None
    res = run(a.quick, a.part or PARTS, previous)
    write_json(path, {"name": NAME, "mode": mode, **res, "status": "ok",
                      "machine": machine_info()})
    print(json.dumps(res["headline"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
