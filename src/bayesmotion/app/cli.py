"""bayesmotion command line.

One concept: the command line, one subcommand per use of the library, each a thin layer that
checks its arguments and calls the library's function.

Commands:
  demo      the main job on the built-in emotional handshakes (fit, posterior, generation,
            inference, report)
  fit       MAP fit of a hierarchical GPDM to DATA
  sample    emcee posterior of a fitted model, saved as netCDF
  generate  motion from a model (mean and sampled rollouts) as BVH, a rollout file and an
            interactive viewer page (optionally a GIF)
  infer     posterior over the emotion of one clip (one or two BVH files), or of every clip
            in a folder on a Dask cluster (a table of answers, resumable)
  evaluate  leave-one-trial-out emotion inference on DATA
  view      an interactive 3-D viewer page (HTML, self-contained) of BVH or rollout files

DATA is builtin:handshakes, a folder of BVH files with labels.csv (file, emotion, couple), or a
Bandai Namco dataset root.

Compiled programs go to JAX's persistent compilation cache (bayesmotion.compile_cache), so a
later command with the same programs reads them instead of compiling them again;
--no-compile-cache (before the command) or BAYESMOTION_COMPILE_CACHE=off turns that off.

Exit codes: 0 success; 2 bad input (missing file, wrong format, unknown emotion, incompatible
model, a number out of range, an output path that cannot be written, a request larger than the
memory available), with one line on stderr and a hint; 1 unexpected error (a bug: rerun with
--debug for the traceback); 130 interrupted.

Every argument is checked before any work: numbers (types, ranges), input paths (they exist),
output paths (writable: nothing is fitted for an --out that cannot be written) and the memory a
command will need (bayesmotion.validate; --no-memory-check turns that check off).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import sys
import warnings
from importlib import resources
from pathlib import Path

from bayesmotion import validate
from bayesmotion.app.demo import run_demo
from bayesmotion.compile_cache import enable_compilation_cache
from bayesmotion.data.files import atomic_write_text
from bayesmotion.datasets.loaders import load_data
from bayesmotion.emotion.batch import infer_many
from bayesmotion.emotion.evidence import calibrate_evidence
from bayesmotion.emotion.infer import PROJECTION_ITER, infer_emotion
from bayesmotion.emotion.ood import OutOfDistributionWarning, UnseenStyleWarning
from bayesmotion.emotion.projection import START_JITTER
from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.evaluate import format_confusion, leave_one_out
from bayesmotion.inference.diagnostics import convergence
from bayesmotion.inference.posterior import format_seconds
from bayesmotion.inference.sample import sample_posterior
from bayesmotion.model.generate import MAX_SAMPLE_MEMORY, SAMPLE_MEMORY
from bayesmotion.model.io import load
from bayesmotion.model.spec import HGPDM
from bayesmotion.optim.minimize import convergence_note
from bayesmotion.viz.animate import animate
from bayesmotion.viz.viewer import load_clips, rollout_clip, write_viewer

EXAMPLES = {
    "demo": "bayesmotion demo --quick --out demo_out",
    "fit": "bayesmotion fit builtin:handshakes --out model.npz",
    "sample": "bayesmotion sample model.npz --out posterior.nc --steps 500",
    "generate": "bayesmotion generate model.npz --emotion happy --frames 60 --samples 4 --out gen/",
    "infer": ("bayesmotion infer model.npz gen/happy_mean_actor0.bvh "
              "gen/happy_mean_actor1.bvh --json"),
    "evaluate": "bayesmotion evaluate model.npz builtin:handshakes",
    "view": "bayesmotion view gen/happy_rollout.npz --out happy.html",
}


class _Parser(argparse.ArgumentParser):
    """argparse, whose usage errors follow the CLI's contract: one line and a hint, exit 2."""

    def error(self, message):
        self.exit(2, f"error: {' '.join(message.split())}\nhint: see '{self.prog} --help'\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="bayesmotion", description=__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.add_argument("--no-compile-cache", action="store_true",
                   help="compile every program afresh instead of reading and writing JAX's "
                        "persistent compilation cache (default: in the user's cache folder, "
                        "or BAYESMOTION_COMPILE_CACHE; 'off' there turns it off too)")
    sub = p.add_subparsers(dest="command", required=True)

    def add(name, help):
        c = sub.add_parser(name, help=help, description=f"{help}\n\nexample: {EXAMPLES[name]}",
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        c.add_argument("--no-memory-check", action="store_true",
                       help="run even when the estimated memory exceeds what is available")
        return c

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
    f.add_argument("--relative-to", default=None, metavar="LABEL",
                   help="with --pose-space affective: model every frame's features relative "
                        "to the mean of the training trials sharing its LABEL (e.g. content), "
                        "for corpora of several actions; new clips need that label (infer "
                        "--group)")
    f.add_argument("--inducing", type=int, default=None, metavar="M",
                   help="the sparse model with M inducing points per layer (O(N M^2) instead "
                        "of O(N^3); for corpora beyond a few thousand frames)")
    f.add_argument("--mapping-noise-floor", type=float, default=0.0, metavar="VAR",
                   help="least noise variance of the bottom and interaction layers, in their "
                        "outputs' units, at most 1 (HGPDM(mapping_noise_floor=...); default "
                        "0: none; 1e-3 keeps generated gestures as smooth as real ones but "
                        "lets long run rollouts wander, see docs/model.md)")
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
                        "(sample_posterior(hmc=True)): far fewer steps, each ~13x dearer")
    s.add_argument("--no-independence", action="store_true",
                   help="leave out the independence step on the hyperparameters "
                        "(sample_posterior(independence=False)); the factorised sampler "
                        "never uses it")
    s.add_argument("--fix-styles", action="store_true",
                   help="hold the training style vectors at the model's and sample the "
                        "hyperparameters alone (sample_posterior(fix_styles=True)): a "
                        "conditional of the posterior, which converges in a few hundred steps")
    g = add("generate", "generate motion from a model")
    g.add_argument("model")
    g.add_argument("--emotion", default="neutral", help="a label or coordinates, e.g. 0.5,0.5,0,0")
    g.add_argument("--couple", default=None)
    g.add_argument("--frames", type=int, default=60)
    g.add_argument("--samples", type=int, default=0)
    g.add_argument("--sample-memory", type=int, default=SAMPLE_MEMORY, metavar="STEPS",
                   help="steps of its own path each step of a sampled rollout is conditioned on, "
                        f"at most {MAX_SAMPLE_MEMORY} (0: each step given the training data "
                        f"alone; default {SAMPLE_MEMORY}); needs --samples")
    g.add_argument("--lookahead", type=float, default=0.0, metavar="WEIGHT",
                   help="keep long rollouts on the training latents: each step also lowers the "
                        "next step's predictive variance, with this weight (0: plain "
                        "predictive means; 10 keeps periodic walk models walking)")
    g.add_argument("--dynamics-style", choices=("requested", "nearest", "registered"),
                   default="requested",
                   help="where the dynamics runs at coordinates between levels: at them "
                        "(requested, the default), at the nearest level with the mapping "
                        "alone at the coordinates (nearest), or at each level, the levels' "
                        "rollouts aligned in time and blended by the coordinates "
                        "(registered; generate(dynamics_style=...))")
    g.add_argument("--pin-feet", action="store_true",
                   help="correct each actor's root path so planted feet do not glide "
                        "(bayesmotion.features.contacts.pin_feet)")
    g.add_argument("--pin-legs", action="store_true",
                   help="--pin-feet, and also hold each planted foot with its own leg (hips, "
                        "knees and ankles turn; pin_feet(legs=True)); for standing motion such "
                        "as gestures")
    g.add_argument("--out", required=True)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--gif", action="store_true", help="also write an animated GIF")
    i = add("infer", "posterior over the emotion of a clip")
    i.add_argument("model")
    i.add_argument("clips", nargs="+",
                   help="one BVH per actor; or one folder of clips (one file per clip, or "
                        "<clip>_actor<a>.bvh per actor), inferred in parallel on Dask")
    i.add_argument("--json", action="store_true")
    i.add_argument("--couple", default=None)
    i.add_argument("--group", default=None,
                   help="for a model fitted with --relative-to: the clips' label (e.g. their "
                        "content, walk), whose training mean their poses are read against")
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
    i.add_argument("--level-starts", type=int, default=1, metavar="K",
                   help="with 'vertices': projections per emotion level, from the level's "
                        "start and K - 1 copies of it jittered by "
                        "--start-jitter, the best kept (default 1; each start adds a "
                        "projection per level)")
    i.add_argument("--start-jitter", type=float, default=START_JITTER, metavar="SD",
                   help=f"with 'vertices': sd of the jitter of the level projections' "
                        f"jittered starts in latent units (default {START_JITTER:g}: the "
                        f"level's start itself; with one start per level, "
                        f"SD > 0 jitters it; --level-starts > 1 needs SD > 0, e.g. 0.02)")
    i.add_argument("--staged-start", action="store_true",
                   help="with 'vertices': start each level's projection in two stages (X* by "
                        "the bottom layer alone, then I* with X* held) instead of at the "
                        "nearest training frames' latents")
    i.add_argument("--max-iter", type=int, default=PROJECTION_ITER, metavar="N",
                   help=f"L-BFGS iterations per projection at most (default "
                        f"{PROJECTION_ITER}); a projection stops earlier where it converges")
    i.add_argument("--workers", type=int, default=2,
                   help="with a folder: processes of the local Dask cluster (default 2)")
    i.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="with a folder: run on this Dask scheduler (e.g. tcp://host:8786) "
                        "instead of a local cluster; every worker must read the clips' paths")
    i.add_argument("--table", default=None, metavar="OUT.csv",
                   help="with a folder: the table of answers, written as clips finish and "
                        "resumed if it exists (default FOLDER/emotions.csv)")
    e = add("evaluate", "leave-one-trial-out emotion inference")
    e.add_argument("model")
    e.add_argument("data")
    e.add_argument("--refit-iter", type=int, default=100)
    e.add_argument("--calibrate", action="store_true",
                   help="also calibrate the label probabilities (the effective frames per "
                        "recording) and the coordinates' likelihood power on the folds "
                        "(cross-fitted)")
    e.add_argument("--save-calibrated", default=None, metavar="OUT",
                   help="with --calibrate: write the model with its label probabilities "
                        "calibrated on all folds to OUT (infer uses it)")
    e.add_argument("--emotion-starts", choices=("nearest", "levels", "vertices"),
                   default="vertices",
                   help="projection starts of every inference (see 'infer')")
    e.add_argument("--level-starts", type=int, default=1, metavar="K",
                   help="projections per emotion level of every inference (see 'infer')")
    e.add_argument("--start-jitter", type=float, default=START_JITTER, metavar="SD",
                   help="jitter of every inference's level projection starts (see 'infer')")
    e.add_argument("--staged-start", action="store_true",
                   help="every inference's level projections start in two stages (see "
                        "'infer')")
    e.add_argument("--max-iter", type=int, default=PROJECTION_ITER, metavar="N",
                   help="L-BFGS iterations per projection of every inference (see 'infer')")
    e.add_argument("--json", default=None, help="write the result to this JSON file")
    v = add("view", "an interactive 3-D viewer page of motion files")
    v.add_argument("files", nargs="+",
                   help="rollout files (.npz from 'generate'; each one clip) or BVH files (one "
                        "clip, a file per actor)")
    v.add_argument("--out", required=True, help="the HTML page to write")
    v.add_argument("--title", default="bayesmotion viewer")
    return p


def _emotion(value: str):
    if "," in value:
        try:
            return [float(x) for x in value.split(",")]
        except ValueError:
            raise BayesmotionError(f"--emotion {value!r}: expected a label or numbers "
                                   f"separated by commas") from None
    return value


def _utf8_text(path: Path) -> str:
    """The text of ``path``, refused unless it is UTF-8 (the loaders read text as UTF-8)."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise BayesmotionError(f"{path}: must be UTF-8 text, but byte 0x{data[e.start]:02x} at "
                               f"offset {e.start} is not; save it as UTF-8 (e.g. 'iconv -f "
                               f"latin1 -t utf-8')") from None


def _data_files(spec: str) -> list:
    """The BVH files a data specification reads (checked: a labels.csv is UTF-8 and every file
    it lists exists); the loader checks everything else."""
    if spec.startswith("builtin:"):
        if spec != "builtin:handshakes":
            return []
        root = resources.files("bayesmotion.datasets") / "builtin"
        return [root / "18_01.bvh", root / "19_01.bvh"]
    root = Path(spec)
    labels = root / "labels.csv"
    if labels.is_file():
        rows = list(csv.DictReader(io.StringIO(_utf8_text(labels), newline="")))
        files = []
        for i, row in enumerate(rows):
            name = row.get("file")
            if not name:
                continue
            if not (root / name).is_file():
                raise BayesmotionError(f"{labels}: line {i + 2} names {name!r}, which is not a "
                                       f"file in {root}; fix the file column")
            files.append(root / name)
        return files
    if root.is_dir():
        return sorted(root.glob("dataset-1_*.bvh")) or sorted(root.glob("data/dataset-1_*.bvh"))
    return []


def _check_data(spec: str, fps: float | None) -> None:
    """Before loading: the data's own files, and ``fps`` no higher than their frame rate
    (resampling up adds frames and memory, no information)."""
    heads = []
    for f in _data_files(spec):
        with resources.as_file(f) as path:
            heads.append(validate.bvh_header(path))
    rates = [1.0 / h[1] for h in heads if h is not None]
    if fps is not None and rates and fps > max(rates) * (1 + 1e-6):
        raise BayesmotionError(f"--fps {fps:g} is above the data's own frame rate "
                               f"({max(rates):.4g} fps): resampling up adds frames, not "
                               f"information; pass --fps {max(rates):.4g} or less")


def _cmd_fit(a):
    if a.fps is not None:
        validate.real(a.fps, "--fps", above=0.0, at_most=validate.MAX_FPS)
    validate.integer(a.max_iter, "--max-iter", low=1)
    validate.integer(a.latent_dim, "--latent-dim", low=1)
    validate.integer(a.interaction_dim, "--interaction-dim", low=1)
    if a.inducing is not None:
        validate.integer(a.inducing, "--inducing", low=2)
    if a.mapping_noise_floor != 0.0:
        validate.real(a.mapping_noise_floor, "--mapping-noise-floor", above=0.0, at_most=1.0)
    validate.output_file(a.out, "--out")
    _check_data(a.data, a.fps)
    ds = load_data(a.data, a.fps)
    N = sum(t.n_frames for t in ds)
    validate.check_memory(
        validate.fit_memory(N, ds.n_actors + 2, ds.n_actors * a.latent_dim + a.interaction_dim,
                            a.inducing),
        f"fitting {N} frames")
    m = HGPDM(latent_dim=a.latent_dim, interaction_dim=a.interaction_dim,
              rest_frames=a.rest_frames, canonical_side=a.canonical_side,
              pose_space=a.pose_space, relative_to=a.relative_to, inducing=a.inducing,
              mapping_noise_floor=a.mapping_noise_floor).fit(
        ds, max_iter=a.max_iter)
    m.save(a.out)
    d = m.diagnostics
    print(f"fitted {len(ds)} trials in {d['seconds']:.1f} s (objective {d['objective']:.1f}; "
          f"{convergence_note(d)}); wrote {a.out}")


def _cmd_sample(a):
    validate.integer(a.steps, "--steps", low=1)
    if a.walkers is not None:
        validate.integer(a.walkers, "--walkers", low=1)
    validate.output_file(a.out, "--out")
    if a.backend is not None:
        validate.output_file(a.backend, "--backend")
        if Path(a.backend).resolve() == Path(a.out).resolve():
            raise BayesmotionError(f"--backend and --out are the same file ({a.out}); the "
                                   f"posterior would overwrite the chain: give two paths")
    m = load(a.model)
    post = sample_posterior(m, n_walkers=a.walkers, n_steps=a.steps, backend=a.backend,
                            factorise=a.factorise, hmc=a.hmc,
                            independence=False if a.no_independence else None,
                            fix_styles=a.fix_styles, check_memory=not a.no_memory_check)
    post.to_netcdf(a.out)
    c = convergence(post)
    print(f"wrote {a.out}: max R-hat {c['max_rhat']:.3f}, min bulk ESS {c['min_ess_bulk']:.0f}, "
          f"acceptance {c['mean_acceptance']:.2f}; {post.info['n_steps']} steps in "
          f"{format_seconds(post.info['seconds'])}")


def _cmd_generate(a):
    validate.integer(a.frames, "--frames", low=1)
    validate.integer(a.samples, "--samples", low=0)
    validate.integer(a.sample_memory, "--sample-memory", low=0, high=MAX_SAMPLE_MEMORY)
    validate.seed(a.seed, "--seed")
    emotion = _emotion(a.emotion)
    out = validate.output_dir(a.out, "--out")
    m = load(a.model)
    if a.frames <= m.spec.order:
        raise BayesmotionError(f"--frames must exceed the model's dynamics order "
                               f"({m.spec.order}), got {a.frames}")
    r = m.generate(emotion=emotion, couple=a.couple, n_frames=a.frames,
                   n_samples=a.samples, seed=a.seed, sample_memory=a.sample_memory,
                   lookahead=a.lookahead, dynamics_style=a.dynamics_style)
    if a.pin_feet or a.pin_legs:
        r = r.pin_feet(legs=a.pin_legs)
    tag = a.emotion.replace(",", "_")
    paths = r.write_bvh(out, prefix=tag)
    for k in range(a.samples):
        paths += r.write_bvh(out, prefix=tag, sample=k)
    r.save(out / f"{tag}_rollout.npz")
    write_viewer(out / f"{tag}.html", [rollout_clip(r, a.emotion, "emotion")],
                 title=f"bayesmotion: {a.emotion}")
    if a.gif:
        # (S, A, T, J, 3) -> sample by sample, actors inside: the order spread_colors expects
        spread = None if r.samples is None else r.samples["positions"].reshape(
            -1, *r.samples["positions"].shape[2:])
        animate(r.to_motion(), out / f"{tag}.gif", spread=spread)
    flag = " (extrapolated beyond the simplex)" if r.extrapolated else ""
    print(f"wrote {len(paths)} BVH files, {tag}_rollout.npz and the viewer {tag}.html to "
          f"{out}{flag}")


def _cmd_view(a):
    for f in a.files:
        validate.input_file(f, "file")
    out = validate.output_file(a.out, "--out")
    clips = load_clips(a.files)
    write_viewer(out, clips, title=a.title)
    print(f"wrote {out} ({len(clips)} clip{'s' if len(clips) > 1 else ''}); open it in a browser")


def _cmd_infer(a):
    validate.seed(a.seed, "--seed")
    validate.integer(a.max_iter, "--max-iter", low=1)
    validate.check_projection_starts(a.emotion_starts, a.level_starts, a.start_jitter,
                                     "--level-starts", "--start-jitter")
    if len(a.clips) == 1 and Path(a.clips[0]).is_dir():
        return _infer_folder(a)
    for c in a.clips:
        validate.input_file(c, "clip")
    m = load(a.model)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OutOfDistributionWarning)
        warnings.simplefilter("always", UnseenStyleWarning)
        ep = infer_emotion(m, a.clips if len(a.clips) > 1 else a.clips[0], couple=a.couple,
                           styles=_group_styles(m, a.group), seed=a.seed,
                           likelihood_power=a.likelihood_power,
                           emotion_starts=a.emotion_starts, level_starts=a.level_starts,
                           start_jitter=a.start_jitter, staged_start=a.staged_start,
                           max_iter=a.max_iter)
    for w in caught:  # the flag is part of the answer: one line on stderr, and in the JSON
        if issubclass(w.category, OutOfDistributionWarning | UnseenStyleWarning):
            print(f"warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if a.json:
        lo, hi = ep.interval(0.9)
        print(json.dumps({"label": ep.label, "levels": list(ep.levels),
                          "mean": ep.mean.tolist(), "interval90": [lo.tolist(), hi.tolist()],
                          "probabilities": ep.probabilities.tolist(),
                          "n_frames": ep.info["n_frames"],
                          "likelihood_power": ep.info["likelihood_power"],
                          "emotion_starts": ep.info["emotion_starts"],
                          "level_starts": ep.info["level_starts"],
                          "start_jitter": ep.info["start_jitter"],
                          "staged_start": ep.info["staged_start"],
                          "max_iter": a.max_iter,
                          "map_objective": ep.info["map_objective"],
                          "out_of_distribution": ep.out_of_distribution,
                          "ood_score": ep.info["ood"]["score"],
                          "unknown_group": ep.info["ood"].get("unknown_group"),
                          "unseen_levels": ep.info["unseen_levels"],
                          "in_distribution_weight": ep.info.get("in_distribution_weight"),
                          "effective_frames": ep.info["effective_frames"]
                          if ep.info["effective_frames"] != float("inf") else None,
                          "evidence_calibrated": ep.info["evidence_calibrated"]}))
    else:
        print(ep)


def _group_styles(model, group) -> dict | None:
    """``infer --group``: the clips' label of the model's ``relative_to``, as a style."""
    rel = model.spec.relative_to
    if group is None:
        if rel is not None:
            raise BayesmotionError(f"the model reads poses relative to their {rel!r} "
                                   f"(fit --relative-to {rel}): give the clips' {rel!r} with "
                                   f"--group, one of {list(model.codecs[0].groups)}")
        return None
    if rel is None:
        raise BayesmotionError("--group is for models fitted with --relative-to; this model "
                               "reads poses on their own")
    return {rel: group}


def _infer_folder(a):
    validate.integer(a.workers, "--workers", low=1)
    validate.input_file(a.model, "model")
    folder = Path(a.clips[0])
    table = validate.output_file(a.table if a.table else folder / "emotions.csv", "--table")
    styles = _group_styles(load(a.model), a.group)
    rows = infer_many(a.model, folder, table, workers=a.workers, scheduler=a.scheduler,
                      styles=styles, seed=a.seed, couple=a.couple,
                      likelihood_power=a.likelihood_power,
                      emotion_starts=a.emotion_starts, level_starts=a.level_starts,
                      start_jitter=a.start_jitter, staged_start=a.staged_start,
                      max_iter=a.max_iter)
    errors = [r for r in rows if r["error"]]
    flagged = sum(str(r["out_of_distribution"]) == "True" for r in rows)
    print(f"wrote {table}: {len(rows)} clips, {len(errors)} failed, {flagged} out of "
          f"distribution")
    for r in errors[:5]:
        print(f"warning: {r['clip']}: {r['error']}", file=sys.stderr)


def _check_fits(m, ds, model_path, data) -> None:
    """Refuse data the model was not fitted on (evaluate warm-starts every fold's refit from
    the model's latents, trial by trial): actors, skeletons, style levels, trials, frames."""
    fix = f"evaluate needs a model fitted on this data ('bayesmotion fit {data} --out ...')"
    if ds.n_actors != m.n_actors:
        raise BayesmotionError(f"{model_path} has {m.n_actors} actor(s) per trial, {data} has "
                               f"{ds.n_actors}; {fix}")
    for a in range(m.n_actors):
        want, got = list(m.skeleton(a).names), list(ds.trials[0].actors[a].skeleton.names)
        if want != got:
            diff = next((f"{w!r} vs {g!r}" for w, g in zip(want, got, strict=False) if w != g),
                        f"{len(want)} vs {len(got)} joints")
            raise BayesmotionError(f"{model_path}'s actor {a} skeleton differs from {data}'s "
                                   f"({diff}); {fix}")
    for f in dict.fromkeys(("emotion", *m.spec.factors)):
        if tuple(ds.levels.get(f, ())) != tuple(m.levels.get(f, ())):
            raise BayesmotionError(f"{model_path} has {f} levels {list(m.levels.get(f, ()))}, "
                                   f"{data} has {list(ds.levels.get(f, ()))}; {fix}")
    fitted = [(t.name, t.n_frames) for t in m.trials]
    given = [(t.name, t.n_frames) for t in ds]
    if fitted != given:
        if len(fitted) != len(given):
            why = f"was fitted on {len(fitted)} trials, the data hold {len(given)}"
        else:
            i = next(i for i, (f, g) in enumerate(zip(fitted, given, strict=True)) if f != g)
            why = (f"trial {i} is {fitted[i][0]!r} of {fitted[i][1]} frames in the model, "
                   f"{given[i][0]!r} of {given[i][1]} frames at {m.fps:g} fps in the data")
        raise BayesmotionError(f"{model_path} {why}; {fix}")


def _cmd_evaluate(a):
    validate.integer(a.refit_iter, "--refit-iter", low=1)
    validate.integer(a.max_iter, "--max-iter", low=1)
    validate.check_projection_starts(a.emotion_starts, a.level_starts, a.start_jitter,
                                     "--level-starts", "--start-jitter")
    if a.json is not None:
        validate.output_file(a.json, "--json")
    if a.save_calibrated is not None:
        if not a.calibrate:
            raise BayesmotionError("--save-calibrated needs --calibrate")
        if a.emotion_starts != "vertices":
            raise BayesmotionError("--save-calibrated needs the levels' evidence: "
                                   "--emotion-starts vertices (the default)")
        validate.output_file(a.save_calibrated, "--save-calibrated")
    m = load(a.model)
    _check_data(a.data, None)
    ds = load_data(a.data, m.fps)
    _check_fits(m, ds, a.model, a.data)
    N = sum(t.n_frames for t in ds)
    validate.check_memory(validate.fit_memory(N, m.n_actors + 2, inducing=m.spec.inducing),
                          f"refitting {N} frames")
    res = leave_one_out(ds, m, refit_iter=a.refit_iter, calibrate=a.calibrate,
                        infer_kwargs={"emotion_starts": a.emotion_starts,
                                      "level_starts": a.level_starts,
                                      "start_jitter": a.start_jitter,
                                      "staged_start": a.staged_start,
                                      "max_iter": a.max_iter})
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
    lab = lambda c: (f"ECE {c['ece']:.3f}, 90% label sets cover {c['label_set_coverage']:.2f}, "
                     f"wrong with P >= 0.99 in {c['confident_wrong']:.2f}")
    print(f"label probabilities: {lab(res['label_calibration'])}")
    if "evidence" in res:
        ev = res["evidence"]
        print(f"label probabilities with the recording effect (n_eff from the other folds, "
              f"median {ev['n_eff']['median']:.3g} frames): {lab(ev['label_calibration'])}")
        if a.save_calibrated:
            calibrate_evidence(m, res).save(a.save_calibrated)
            print(f"calibrated model (n_eff {ev['n_eff_all_trials']:.3g} frames) written to "
                  f"{a.save_calibrated}")
    if "baselines" in res:
        print("baselines: " + ", ".join(f"{k} {v:.2f}" for k, v in res["baselines"].items()))
    if a.json:
        atomic_write_text(Path(a.json), json.dumps(res, indent=1))


def _cmd_demo(a):
    validate.seed(a.seed, "--seed")
    validate.output_dir(a.out, "--out")
    summary = run_demo(Path(a.out), quick=a.quick, seed=a.seed)
    print(f"demo finished in {summary['seconds_total']:.0f} s; open {Path(a.out) / 'report.html'}")


HINTS = {
    "ModelFileError": "is this a model written by 'bayesmotion fit'?",
    "BVHError": "check the BVH file named above",
    "SkeletonMismatchError": "the clip must use the model's skeleton (same joint names)",
}


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _input_error(e: Exception) -> str | None:
    """The one-line message of an exception that reports bad input or a machine's limit rather
    than a bug, else None."""
    if isinstance(e, UnicodeDecodeError):
        return (f"a text input is not UTF-8 ({e.reason}: byte 0x{e.object[e.start]:02x} at "
                f"offset {e.start}); save the file as UTF-8")
    if isinstance(e, MemoryError):
        return ("ran out of memory; ask for less (fewer frames, samples, steps or walkers, a "
                "lower --fps)")
    if isinstance(e, OSError) and e.filename is not None:
        return f"{e.filename}: {e.strerror or e}"
    return None


@contextlib.contextmanager
def _tidy_warnings(debug: bool):
    """At the command line, each warning is one line on stderr (``warning: ...``), without the
    file and source line that a program's author would want; and deprecation notices
    (``FutureWarning``, ``DeprecationWarning``), which only the package's dependencies issue
    (e.g. arviz's notice of its refactor) and which the user can do nothing about, are not
    shown. ``--debug`` shows every warning as Python does."""
    with warnings.catch_warnings():
        if not debug:
            for category in (FutureWarning, DeprecationWarning, PendingDeprecationWarning):
                warnings.filterwarnings("ignore", category=category)

            def show(message, category, filename, lineno, file=None, line=None):
                print(f"warning: {_one_line(message)}", file=sys.stderr)

            warnings.showwarning = show
        yield


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parser().parse_args(argv)
    except SystemExit as e:  # --help (0), or a usage error already printed as one line (2)
        return e.code if isinstance(e.code, int) else 2

    try:
        with validate.memory_checks(not args.no_memory_check), _tidy_warnings(args.debug):
            if not args.no_compile_cache:
                enable_compilation_cache()
            globals()[f"_cmd_{args.command}"](args)
        return 0
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BayesmotionError as e:
        if args.debug:
            raise
        hint = HINTS.get(type(e).__name__, f"see 'bayesmotion {args.command} --help'")
        print(f"error: {_one_line(e)}\nhint: {hint}", file=sys.stderr)
        return 2
    except Exception as e:  # unexpected: one line unless --debug
        if args.debug:
            raise
        message = _input_error(e)
        if message is not None:
            print(f"error: {_one_line(message)}\nhint: see 'bayesmotion {args.command} --help'",
                  file=sys.stderr)
            return 2
        print(f"error: unexpected {type(e).__name__}: {_one_line(e)}\nhint: rerun with --debug "
              f"and report the traceback", file=sys.stderr)
        return 1
