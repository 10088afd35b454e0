"""bayesmotion command line.

Commands:
  demo      the main job on the built-in emotional handshakes (fit, posterior, generation,
            inference, report)
  fit       MAP fit of a hierarchical GPDM to DATA
  sample    emcee posterior of a fitted model, saved as netCDF
  generate  handshakes from a model (mean and sampled rollouts) as BVH + GIF
  infer     posterior over the emotion of one clip (one or two BVH files)
  evaluate  leave-one-trial-out emotion inference on DATA

DATA is builtin:handshakes, a folder of BVH files with labels.csv (file, emotion, couple), or a
Bandai Namco dataset root.

Exit codes: 0 success; 2 bad input (missing file, wrong format, unknown emotion, incompatible
model); 1 unexpected error (rerun with --debug for the traceback); 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bayesmotion.app.demo import run_demo
from bayesmotion.data.files import atomic_write_text
from bayesmotion.datasets.loaders import load_data
from bayesmotion.emotion.infer import infer_emotion
from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.evaluate import format_confusion, leave_one_out
from bayesmotion.inference.diagnostics import convergence
from bayesmotion.inference.sample import sample_posterior
from bayesmotion.model.io import load
from bayesmotion.model.spec import HGPDM
from bayesmotion.viz.animate import animate

EXAMPLES = {
    "demo": "bayesmotion demo --quick --out demo_out",
    "fit": "bayesmotion fit builtin:handshakes --out model.npz",
    "sample": "bayesmotion sample model.npz --out posterior.nc --steps 500",
    "generate": "bayesmotion generate model.npz --emotion happy --frames 60 --samples 4 --out gen/",
    "infer": ("bayesmotion infer model.npz gen/happy_mean_actor0.bvh "
              "gen/happy_mean_actor1.bvh --json"),
    "evaluate": "bayesmotion evaluate model.npz builtin:handshakes",
}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bayesmotion", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", required=True)

    def add(name, help):
        return sub.add_parser(name, help=help, description=f"{help}\n\nexample: {EXAMPLES[name]}",
                              formatter_class=argparse.RawDescriptionHelpFormatter)

    d = add("demo", "the main job on the built-in emotional handshakes")
    d.add_argument("--out", required=True, help="output folder")
    d.add_argument("--quick", action="store_true", help="small settings (< 3 min)")
    d.add_argument("--seed", type=int, default=0)
    f = add("fit", "MAP fit of a hierarchical GPDM")
    f.add_argument("data")
    f.add_argument("--out", required=True)
    f.add_argument("--fps", type=float, default=None)
    f.add_argument("--max-iter", type=int, default=1000)
    f.add_argument("--latent-dim", type=int, default=6)
    f.add_argument("--interaction-dim", type=int, default=6)
    f.add_argument("--rest-frames", action="store_true",
                   help="turn each joint's frame to its mean rotation before encoding (rigs "
                        "near gimbal lock, e.g. Bandai's spine); new clips get the same frames")
    f.add_argument("--canonical-side", action="store_true",
                   help="mirror one-actor clips that move to the actor's right, at fit and at "
                        "inference (label-free)")
    f.add_argument("--pose-space", choices=("angles", "affective"), default="angles",
                   help="model joint angles (default; the model generates motion) or the 18 "
                        "affective pose features of every frame (infers emotion across "
                        "actions; cannot generate)")
    s = add("sample", "emcee posterior of a fitted model")
    s.add_argument("model")
    s.add_argument("--out", required=True)
    s.add_argument("--steps", type=int, default=2000)
    s.add_argument("--walkers", type=int, default=None)
    s.add_argument("--backend", default=None, help="HDF5 file to save/resume the chain")
    s.add_argument("--factorise", action="store_true",
                   help="sample gamma and the other coordinates with two ensembles "
                        "(sample_posterior(factorise=True)) instead of one")
    s.add_argument("--hmc", action="store_true",
                   help="add ensemble-preconditioned HMC steps to the default moves "
                        "(sample_posterior(hmc=True)): far fewer steps, each ~18x dearer")
    s.add_argument("--no-independence", action="store_true",
                   help="leave out the independence step on the hyperparameters "
                        "(sample_posterior(independence=False)); the factorised sampler "
                        "never uses it")
    g = add("generate", "generate handshakes from a model")
    g.add_argument("model")
    g.add_argument("--emotion", default="neutral", help="a label or coordinates, e.g. 0.5,0.5,0,0")
    g.add_argument("--couple", default=None)
    g.add_argument("--frames", type=int, default=60)
    g.add_argument("--samples", type=int, default=0)
    g.add_argument("--out", required=True)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--gif", action="store_true", help="also write an animated GIF")
    i = add("infer", "posterior over the emotion of a clip")
    i.add_argument("model")
    i.add_argument("clips", nargs="+", help="one BVH per actor")
    i.add_argument("--json", action="store_true")
    i.add_argument("--couple", default=None)
    i.add_argument("--seed", type=int, default=0)
    i.add_argument("--likelihood-power", type=float, default=1.0,
                   help="eta of the tempered posterior (from 'evaluate --calibrate')")
    i.add_argument("--emotion-starts", choices=("nearest", "levels", "vertices"),
                   default="vertices",
                   help="'vertices' (default): choose the level by the Laplace evidence of a "
                        "projection with the emotion held at each level; 'nearest': one "
                        "projection from the nearest training frames (about 3x faster); "
                        "'levels': that start and one from each emotion level's frames, the "
                        "best optimum kept")
    e = add("evaluate", "leave-one-trial-out emotion inference")
    e.add_argument("model")
    e.add_argument("data")
    e.add_argument("--refit-iter", type=int, default=100)
    e.add_argument("--calibrate", action="store_true",
                   help="also calibrate the likelihood power on the folds (cross-fitted)")
    e.add_argument("--emotion-starts", choices=("nearest", "levels", "vertices"),
                   default="vertices",
                   help="projection starts of every inference (see 'infer')")
    e.add_argument("--json", default=None, help="write the result to this JSON file")
    return p


def _emotion(value: str):
    if "," in value:
        try:
            return [float(x) for x in value.split(",")]
        except ValueError:
            raise BayesmotionError(f"--emotion {value!r}: expected a label or numbers "
                                   f"separated by commas") from None
    return value


def _cmd_fit(a):
    ds = load_data(a.data, a.fps)
    m = HGPDM(latent_dim=a.latent_dim, interaction_dim=a.interaction_dim,
              rest_frames=a.rest_frames, canonical_side=a.canonical_side,
              pose_space=a.pose_space).fit(
        ds, max_iter=a.max_iter)
    m.save(a.out)
    d = m.diagnostics
    print(f"fitted {len(ds)} trials in {d['seconds']:.1f} s ({d['iterations']} iterations, "
          f"objective {d['objective']:.1f}, {d['message']}); wrote {a.out}")


def _cmd_sample(a):
    m = load(a.model)
    post = sample_posterior(m, n_walkers=a.walkers, n_steps=a.steps, backend=a.backend,
                            factorise=a.factorise, hmc=a.hmc,
                            independence=False if a.no_independence else None)
    post.to_netcdf(a.out)
    c = convergence(post)
    print(f"wrote {a.out}: max R-hat {c['max_rhat']:.3f}, min bulk ESS {c['min_ess_bulk']:.0f}, "
          f"acceptance {c['mean_acceptance']:.2f}")


def _cmd_generate(a):
    m = load(a.model)
    r = m.generate(emotion=_emotion(a.emotion), couple=a.couple, n_frames=a.frames,
                   n_samples=a.samples, seed=a.seed)
    out = Path(a.out)
    tag = a.emotion.replace(",", "_")
    paths = r.write_bvh(out, prefix=tag)
    for k in range(a.samples):
        paths += r.write_bvh(out, prefix=tag, sample=k)
    if a.gif:
        # (S, A, T, J, 3) -> sample by sample, actors inside: the order spread_colors expects
        spread = None if r.samples is None else r.samples["positions"].reshape(
            -1, *r.samples["positions"].shape[2:])
        animate(r.to_motion(), out / f"{tag}.gif", spread=spread)
    flag = " (extrapolated beyond the simplex)" if r.extrapolated else ""
    print(f"wrote {len(paths)} BVH files to {out}{flag}")


def _cmd_infer(a):
    m = load(a.model)
    for c in a.clips:
        if not Path(c).is_file():
            raise BayesmotionError(f"{c}: no such file")
    ep = infer_emotion(m, a.clips if len(a.clips) > 1 else a.clips[0], couple=a.couple,
                       seed=a.seed, likelihood_power=a.likelihood_power,
                       emotion_starts=a.emotion_starts)
    if a.json:
        lo, hi = ep.interval(0.9)
        print(json.dumps({"label": ep.label, "levels": list(ep.levels),
                          "mean": ep.mean.tolist(), "interval90": [lo.tolist(), hi.tolist()],
                          "probabilities": ep.probabilities.tolist(),
                          "n_frames": ep.info["n_frames"],
                          "likelihood_power": ep.info["likelihood_power"],
                          "emotion_starts": ep.info["emotion_starts"],
                          "map_objective": ep.info["map_objective"]}))
    else:
        print(ep)


def _cmd_evaluate(a):
    m = load(a.model)
    ds = load_data(a.data, m.fps)
    res = leave_one_out(ds, m, refit_iter=a.refit_iter, calibrate=a.calibrate,
                        infer_kwargs={"emotion_starts": a.emotion_starts})
    print(format_confusion(res))
    hpd = lambda r: "" if r.get("hpd_coverage") is None else \
        f"highest-density region {r['hpd_coverage']:.2f}, "
    print(f"coverage of the true label at {res['credible_level']:.0%}: {hpd(res)}ellipsoid "
          f"{res['coverage']:.2f}, label set {res['label_set_coverage']:.2f}, all coordinate "
          f"intervals {res['interval_coverage']:.2f}")
    if "calibrated" in res and "error" in res["calibrated"]:
        print(f"tempered posteriors: {res['calibrated']['error']}")
    elif "calibrated" in res:
        c = res["calibrated"]
        print(f"tempered posteriors (likelihood power calibrated on the other folds, median "
              f"{c['likelihood_power']['median']:.3g}): {hpd(c)}ellipsoid {c['coverage']:.2f}, "
              f"accuracy {c['accuracy']:.2f}; for new clips use --likelihood-power "
              f"{c['likelihood_power_all_trials']:.3g}")
    if "baselines" in res:
        print("baselines: " + ", ".join(f"{k} {v:.2f}" for k, v in res["baselines"].items()))
    if a.json:
        atomic_write_text(Path(a.json), json.dumps(res, indent=1))


def _cmd_demo(a):
    summary = run_demo(Path(a.out), quick=a.quick, seed=a.seed)
    print(f"demo finished in {summary['seconds_total']:.0f} s; open {Path(a.out) / 'report.html'}")


HINTS = {
    "ModelFileError": "is this a model written by 'bayesmotion fit'?",
    "BVHError": "check the BVH file named above",
    "SkeletonMismatchError": "the clip must use the model's skeleton (same joint names)",
}


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)

    try:
        globals()[f"_cmd_{args.command}"](args)
        return 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BayesmotionError as e:
        if args.debug:
            raise
        hint = HINTS.get(type(e).__name__, f"see 'bayesmotion {args.command} --help'")
        print(f"error: {e}\nhint: {hint}", file=sys.stderr)
        return 2
    except Exception as e:  # unexpected: one line unless --debug
        if args.debug:
            raise
        print(f"error: unexpected {type(e).__name__}: {e}\nhint: rerun with --debug and report "
              f"the traceback", file=sys.stderr)
        return 1
