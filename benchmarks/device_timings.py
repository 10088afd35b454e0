"""The same calls timed on each device JAX runs on: this CPU and, when one is lent, a GPU.

    python benchmarks/device_timings.py [--quick]         # this machine alone -> results/*_cpu
    python benchmarks/device_timings.py --part OUT.json   # one device's part only
    python benchmarks/device_timings.py --alone OUT.json  # a part's own table -> results/
    python benchmarks/device_timings.py --merge CPU.json GPU.json # side by side -> results/

On the demo's model (``HGPDM()`` on the built-in handshakes at 10 fps without the four held-out
trials): a MAP fit of 300 L-BFGS iterations (first call, compilation included, then the same
fit again with warm caches), 20 default emcee steps (after a first short run that compiles),
``infer_emotion`` of held-out trials (the first call apart, then the others one by one; with
the default style sampler and projection batching, with emcee and one projection at a time,
and with the other batching; seconds per stage of the warm calls) and ``generate`` of 500
frames with its variances and 8 sampled rollouts (first and warm calls).

Each device's part records the JAX backend and device, versions and the machine; ``--merge``
puts the parts side by side with the GPU / CPU ratio of each warm timing (the fastest warm call
of each side). The README rows say whether a GPU is at least as fast as this CPU for
``infer_emotion`` and ``generate``. Each part records its machine, versions and the load
average at its start and end: the two parts run different Python and jax builds (the GPU
machine's own), and the CPU's cores may be shared.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import RESULTS, headline, machine_info, write_json  # noqa: E402

NAME = "device_timings"
FULL = {"fps": 10.0, "max_iter": 300, "emcee_steps": 20, "gen_frames": 500, "gen_samples": 8,
        "infer_clips": 4}
QUICK = {"fps": 5.0, "max_iter": 20, "emcee_steps": 4, "gen_frames": 40, "gen_samples": 2,
         "infer_clips": 2}


def _timed(fn):
    t = time.perf_counter()
    out = fn()
    s = time.perf_counter() - t
    print(f"  {s:.3f} s", file=sys.stderr, flush=True)  # progress, should a run be cut short
    return out, s


def part(quick: bool) -> dict:
    """Time the calls on JAX's default device."""
    import warnings

    import jax

    from bayesmotion.app.demo import _split
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.inference.posterior import ChainTooShortWarning
    from bayesmotion.inference.sample import sample_posterior
    from bayesmotion.model.spec import HGPDM

    cfg = QUICK if quick else FULL
    dev = jax.devices()[0]
    train, held = _split(load_handshakes(fps=cfg["fps"]))
    out = {"backend": jax.default_backend(), "device": str(getattr(dev, "device_kind", dev)),
           "settings": cfg, "machine": machine_info(), "n_train_frames": sum(
               t.n_frames for t in train)}
    model, s = _timed(lambda: HGPDM().fit(train, max_iter=cfg["max_iter"], progress=False))
    out["fit_first_s"] = s
    out["fit_iterations"] = model.diagnostics["iterations"]
    _, s = _timed(lambda: HGPDM().fit(train, max_iter=cfg["max_iter"], progress=False))
    out["fit_warm_s"] = s
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        _, s = _timed(lambda: sample_posterior(model, n_steps=4, progress=False, seed=1))
        out["emcee_first_s"] = s
        post, s = _timed(lambda: sample_posterior(model, n_steps=cfg["emcee_steps"],
                                                  progress=False, seed=2))
    out["emcee_walkers"] = post.info["n_walkers"]
    out["emcee_step_s"] = s / cfg["emcee_steps"]
    clips = list(held)[:cfg["infer_clips"]]
    variants = {}
    for name, sampler, batched in _variants():
        variants[name] = _infer_times(model, clips, sampler, batched)
    out["infer_variants"] = variants
    out["infer_first_s"] = variants["default"]["first_s"]
    out["infer_warm_s"] = variants["default"]["warm_s"]
    gen = []
    for k in range(3):
        _, s = _timed(lambda k=k: model.generate(emotion="happy", couple="c1",
                                                 n_frames=cfg["gen_frames"],
                                                 n_samples=cfg["gen_samples"], seed=k))
        gen.append(s)
    out["generate_first_s"], out["generate_warm_s"] = gen[0], gen[1:]
    out["generate_warm_frames_per_s"] = cfg["gen_frames"] / min(gen[1:])
    out["mode"] = "quick" if quick else "full"
    out["load_average_at_end"] = machine_info()["load_average_1_5_15"]
    return out


def _variants():
    """(name, style sampler, batched projections) of the infer_emotion timings: the defaults
    (the JAX ensemble; projections batched on an accelerator only), emcee with one projection
    at a time (the defaults before the ensemble and the batching), and the ensemble with the
    other batching choice."""
    from bayesmotion.emotion.projection import batch_jobs

    on = batch_jobs()
    return (("default", "ensemble", on), ("emcee_one_at_a_time", "emcee", False),
            ("ensemble_batched" if not on else "ensemble_one_at_a_time", "ensemble", not on))


def _infer_times(model, clips, sampler: str, batched: bool) -> dict:
    """Times of infer_emotion over ``clips`` (the first call apart: it compiles) with the given
    style sampler and projection batching; the warm calls' median seconds per stage."""
    import numpy as np

    from bayesmotion.emotion import projection
    from bayesmotion.emotion.infer import infer_emotion

    default = projection.batch_jobs
    projection.batch_jobs = lambda: batched
    try:
        times, stages = [], []
        for k, trial in enumerate(clips):
            ep, s = _timed(lambda trial=trial, k=k: infer_emotion(
                model, trial, couple=trial.labels["couple"], seed=k, method=sampler))
            times.append(s)
            stages.append(ep.info["stage_seconds"])
    finally:
        projection.batch_jobs = default
    warm = stages[1:] or stages
    return {"sampler": sampler, "batched_projections": batched, "first_s": times[0],
            "warm_s": times[1:], "warm_stage_seconds_median": {
                name: float(np.median([st[name] for st in warm])) for name in warm[0]}}


WARM = (("fit_warm_s", "MAP fit (warm)"), ("emcee_step_s", "emcee step"),
        ("infer_warm_s", "infer_emotion per clip (warm)"),
        ("generate_warm_s", "generate 500 frames + 8 samples (warm)"))


def _warm(p: dict, key: str) -> float:
    v = p[key]
    return min(v) if isinstance(v, list) else v


def merge(cpu: dict, gpu: dict) -> dict:
    """The two parts side by side, with the GPU / CPU ratio of each warm timing."""
    rows, ratio = [], {}
    for key, label in WARM:
        c, g = _warm(cpu, key), _warm(gpu, key)
        ratio[key] = g / c
        faster = g <= c
        target = "GPU <= CPU" if key in ("infer_warm_s", "generate_warm_s") else ""
        rows.append(headline(f"{label}: {gpu['device']} vs CPU", round(g / c, 2), "x CPU time",
                             target, faster if target else None,
                             f"GPU {g:.3g} s, CPU {c:.3g} s"))
    for name in gpu.get("infer_variants", {}):
        if name == "default" or name not in cpu.get("infer_variants", {}):
            continue
        g, c = (min(p["infer_variants"][name]["warm_s"]) for p in (gpu, cpu))
        ratio[f"infer_{name}"] = g / c
        rows.append(headline(f"infer_emotion per clip (warm), {name.replace('_', ' ')}: "
                             f"{gpu['device']} vs CPU", round(g / c, 2), "x CPU time", "",
                             None, f"GPU {g:.3g} s, CPU {c:.3g} s"))
    machine = {**cpu["machine"], "load_average_at_start": cpu["machine"]["load_average_1_5_15"]}
    return {"cpu": cpu, "gpu": gpu, "gpu_over_cpu": ratio, "headline": rows,
            "mode": cpu.get("mode", "full"),
            "settings": cpu["settings"], "machine": machine}


def alone(p: dict) -> dict:
    """One device's part with its headline rows (no side-by-side): the warm timings, and
    infer_emotion's per variant."""
    rows = [headline(f"{label} on {p['backend']}", round(_warm(p, key), 3), "s")
            for key, label in WARM]
    for name, v in p.get("infer_variants", {}).items():
        st = v["warm_stage_seconds_median"]
        rows.append(headline(
            f"infer_emotion per clip (warm), {name.replace('_', ' ')}, on {p['backend']}",
            round(min(v["warm_s"]), 3), "s", "", None,
            f"style sampler {v['sampler']}, projections "
            f"{'batched' if v['batched_projections'] else 'one at a time'}; median stage "
            f"seconds: projection {st['project']:.3f}, sampling {st['sample']:.3f}"))
    return {"cpu" if p["backend"] == "cpu" else "gpu": p, "headline": rows,
            "settings": p["settings"], "mode": p.get("mode", "full"), "machine": p["machine"]}


def run(quick: bool) -> dict:
    """This machine alone (the suite's entry point): its part, no GPU row."""
    return alone(part(quick))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--part", default=None, help="write this device's part to this file")
    ap.add_argument("--merge", nargs=2, metavar=("CPU", "GPU"), default=None)
    ap.add_argument("--alone", default=None, metavar="PART",
                    help="write a part's own table to results/device_timings_<backend>.json")
    a = ap.parse_args(argv)
    if a.merge:
        cpu, gpu = (json.loads(Path(p).read_text()) for p in a.merge)
        write_json(RESULTS / f"{NAME}.json", merge(cpu, gpu))
        return 0
    if a.part:
        write_json(Path(a.part), part(a.quick))
        return 0
    r = alone(json.loads(Path(a.alone).read_text())) if a.alone else run(a.quick)
    backend = "cpu" if "cpu" in r else "gpu"
    write_json(RESULTS / f"{NAME}_{backend}.json", r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
