"""The main job: ``bayesmotion demo --out DIR [--quick]`` on the built-in emotional handshakes.

MAP fit -> emcee posterior -> posterior-predictive handshakes for each emotion and an
interpolation series -> emotion inference on held-out trials -> report.html + summary.json.
"""

from __future__ import annotations

import html
import json
import time
from pathlib import Path

import numpy as np

from bayesmotion.app.report import table, write_report
from bayesmotion.data.files import atomic_write_text
from bayesmotion.datasets import load_handshakes
from bayesmotion.evaluation.evaluate import (
    confusion_matrix,
    infer_flagged,
    interval_coverage,
    online_sharpening,
)
from bayesmotion.inference.diagnostics import convergence
from bayesmotion.inference.sample import sample_posterior
from bayesmotion.model.spec import HGPDM
from bayesmotion.optim.minimize import convergence_note
from bayesmotion.validate import output_dir
from bayesmotion.viz.animate import animate
from bayesmotion.viz.plots import save_figure
from bayesmotion.viz.posterior import plot_posterior
from bayesmotion.viz.viewer import rollout_clip, viewer_fragment

SETTINGS = {
    # quick: sized for the 3-minute target on 2 cores. Its posterior section samples the
    # hyperparameters with the style vectors held at the MAP (sample_posterior(fix_styles=True)),
    # a conditional of the posterior that converges within this budget; the whole posterior
    # of this model reaches max R-hat <= 1.05 at 400 steps (168 s), not at 200
    # (benchmarks/results/demo_posterior.json)
    "quick": {"fps": 10.0, "max_iter": 150, "n_steps": 200, "fix_styles": True, "n_draws": 3,
              "n_samples": 3, "infer_steps": 150, "gif_stride": 2},
    # full: the whole posterior, style vectors included, for as many steps as the default
    # sampler needs at this size for max R-hat <= 1.01 and min bulk ESS >= 400
    # (benchmarks/results/posterior_convergence.json: same model, sampler and seed). At 20 fps
    # (N = 680 training frames) one emcee step of the dense posterior costs about 8x more (N^3),
    # which does not fit.
    "full": {"fps": 10.0, "max_iter": 1000, "n_steps": 1200, "fix_styles": False, "n_draws": 8,
             "n_samples": 8, "infer_steps": 400, "gif_stride": 1},
}

POSTERIOR_NOTE = {
    True: ("This quick run samples the hyperparameters (gamma, beta, alpha, the AR "
           "coefficients: {ndim} coordinates) with the training style vectors held at the MAP: "
           "p(hyperparameters | styles, latents), a conditional of the posterior, not the "
           "posterior. Its draws are nearly independent; the generated handshakes' spread "
           "across draws leaves out the styles' uncertainty. The full demo (bayesmotion demo, "
           "without --quick) samples the style vectors too."),
    False: ("The whole posterior over the hyperparameters and the training style vectors "
            "({ndim} coordinates), the latents at the MAP. Its convergence diagnostics, over "
            "the sampled coordinates and the style vectors' Gram entries, are in the table; "
            "benchmarks/results/posterior_convergence.json follows the same chain to 2,000 "
            "steps."),
}


def _split(ds):
    """Hold out couple c2's last repetition of every emotion (4 trials)."""
    held = [i for i, t in enumerate(ds) if t.labels.get("couple") == "c2"
            and t.labels.get("repetition") == "2"]
    train = [i for i in range(len(ds)) if i not in held]
    return ds.take(train), ds.take(held)


def _coverage(model, trial, ep, qs=(0.5, 0.9)):
    """Coverage of the trial's true joint positions by the predictive intervals when generating
    from its inferred start (analytic one-step variance + the sampled rollouts' spread), overall
    and per one-second horizon (:func:`bayesmotion.evaluation.evaluate.interval_coverage`)."""
    r = model.generate(emotion=trial.labels["emotion"], couple=trial.labels.get("couple"),
                       n_frames=trial.n_frames, n_samples=8,
                       start=ep.latents["I"][:model.spec.order])
    truth = np.stack([a.positions() for a in trial.actors])
    return interval_coverage(truth, r.positions, r.positions_var + r.sample_var["positions"],
                             qs, fps=model.fps, n_observed=model.spec.order)


def run_demo(out: Path, quick: bool = False, seed: int = 0) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    cfg = SETTINGS["quick" if quick else "full"]
    out = output_dir(out, "out")  # before any work: a folder that exists or can be created
    (out / "bvh").mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    summary: dict = {"settings": {**cfg, "quick": quick, "seed": seed}}
    ds = load_handshakes(seed=seed, fps=cfg["fps"])
    train, held = _split(ds)
    summary["data"] = {"trials": len(ds), "train": len(train), "held_out": len(held),
                       "frames_per_trial": ds[0].n_frames, "fps": cfg["fps"]}
    stages: dict = {}
    t_stage = time.perf_counter()

    def stage(name):  # wall seconds of each step of the demo, in summary["stage_seconds"]
        nonlocal t_stage
        now = time.perf_counter()
        stages[name] = round(now - t_stage, 2)
        t_stage = now

    # 1. MAP fit
    model = HGPDM().fit(train, max_iter=cfg["max_iter"], seed=seed)
    model.save(out / "model.npz")
    d = model.diagnostics
    summary["fit"] = {k: d[k] for k in ("seconds", "iterations", "objective",
                                        "initial_objective", "converged", "message", "grad_norm")}
    summary["fit"]["convergence_note"] = convergence_note(d)
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot(d["trace"])
    ax.set(xlabel="L-BFGS iteration", ylabel="negative log-posterior", title="MAP fit")
    fig.tight_layout()
    save_figure(fig, out / "fit_trace.png", dpi=90)
    plt.close(fig)
    stage("fit")
    # 2. posterior
    t0 = time.perf_counter()
    post = sample_posterior(model, n_steps=cfg["n_steps"], seed=seed,
                            fix_styles=cfg["fix_styles"])
    post.to_netcdf(out / "posterior.nc")
    conv = convergence(post)
    summary["posterior"] = {**conv, "seconds": time.perf_counter() - t0,
                            "style_vectors": "held at the MAP" if cfg["fix_styles"]
                            else "sampled", "n_coordinates": post.target.ndim,
                            "n_walkers": post.info["n_walkers"], "n_steps": post.info["n_steps"],
                            "burn": post.info["burn"], "thin": post.info["thin"],
                            "max_tau": float(np.max(post.info["tau"])),
                            "warning": post.info.get("warning")}
    plot_posterior(post, path=out / "trace.png", dpi=70)
    stage("posterior")
    # 3. posterior-predictive handshakes
    T = ds[0].n_frames
    gifs, gen, clips = [], {}, []
    for e in model.levels["emotion"]:
        r = post.generate(emotion=e, couple="c1", n_frames=T, n_samples=cfg["n_samples"],
                          n_draws=cfg["n_draws"], seed=seed)
        r.write_bvh(out / "bvh", prefix=e)
        gif = out / f"{e}.gif"
        samples = r.samples["positions"][: 3 * cfg["n_samples"]]  # (S, A, T, J, 3)
        animate(r.to_motion(), gif, stride=cfg["gif_stride"],  # sample by sample, actors inside
                spread=samples.reshape(-1, *samples.shape[2:]))
        gifs.append(gif)
        clips.append(rollout_clip(r, e, "emotion (posterior predictive)"))
        parts = r.variance_parts["positions"]
        gen[e] = {"position_var_within": float(np.mean(parts["within"])),
                  "position_var_between": float(np.mean(parts["between"])),
                  "min_hand_distance": _hand_distance(r)}
    summary["generation"] = gen
    stage("generation")
    # 4. interpolation series neutral -> happy, inferred back
    levels = list(model.levels["emotion"])
    interp = []
    for s in (0.0, 0.25, 0.5, 0.75, 1.0):
        c = np.zeros(len(levels))
        c[levels.index("neutral")], c[levels.index("happy")] = 1 - s, s
        r = model.generate(emotion=c, couple="c1", n_frames=T)
        clips.append(rollout_clip(r, f"happy weight {s:.2f}", "interpolation neutral -> happy"))
        ep = infer_flagged(model, r.Y, couple="c1", n_steps=cfg["infer_steps"], seed=seed,
                           latent_uncertainty=False)
        lo, hi = ep.interval(0.9)
        interp.append({"s": s, "inferred_happy": float(ep.mean[levels.index("happy")]),
                       "inferred_neutral": float(ep.mean[levels.index("neutral")]),
                       "happy_interval90": [float(lo[levels.index("happy")]),
                                            float(hi[levels.index("happy")])],
                       "region90_covers": ep.region_contains(c, 0.9),
                       "hpd90_covers": ep.hpd_contains(c, 0.9)})
    summary["interpolation"] = {
        "series": interp,
        "region90_coverage": float(np.mean([x["region90_covers"] for x in interp])),
        "hpd90_coverage": float(np.mean([x["hpd90_covers"] for x in interp])),
        "mean_abs_error": float(np.mean([abs(x["inferred_happy"] - x["s"]) for x in interp]))}
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([x["s"] for x in interp], [x["inferred_happy"] for x in interp], "o-")
    ax.plot([0, 1], [0, 1], "k:")
    ax.set(xlabel="generated happy weight s", ylabel="inferred happy coordinate")
    fig.tight_layout()
    save_figure(fig, out / "interpolation.png", dpi=90)
    plt.close(fig)
    stage("interpolation")
    # 5. inference on held-out trials
    rows, true, pred, cover = [], [], [], []
    for trial in held:
        ep = infer_flagged(model, trial, couple=trial.labels["couple"],
                           n_steps=cfg["infer_steps"], seed=seed)
        lo, hi = ep.interval(0.9)
        k = levels.index(trial.labels["emotion"])
        truth = np.eye(len(levels))[k]
        true.append(trial.labels["emotion"])
        pred.append(ep.label)
        cover.append(_coverage(model, trial, ep))
        rows.append([trial.name, trial.labels["emotion"], ep.label,
                     " ".join(f"{m:.2f}" for m in ep.mean),
                     ep.hpd_contains(truth, 0.9), ep.region_contains(truth, 0.9),
                     bool(np.all((truth >= lo) & (truth <= hi)))])
    C = confusion_matrix(true, pred, levels)
    summary["inference"] = {
        "accuracy": float(np.mean([t == p for t, p in zip(true, pred, strict=True)])),
        "confusion_percent": C.tolist(), "levels": levels,
        "hpd90_covers_truth": float(np.mean([r[-3] for r in rows])),
        "region90_covers_truth": float(np.mean([r[-2] for r in rows])),
        "interval90_covers_truth": float(np.mean([r[-1] for r in rows])),
        "position_coverage": {q: float(np.mean([c["overall"][q] for c in cover]))
                              for q in ("0.5", "0.9")},
        "position_coverage_first_second": {
            q: float(np.mean([c["first_second"][q] for c in cover])) for q in ("0.5", "0.9")},
        "position_coverage_by_horizon": [
            {"from_s": b["from_s"], "to_s": b["to_s"],
             **{q: float(np.mean([c["by_horizon"][i][q] for c in cover])) for q in ("0.5", "0.9")}}
            for i, b in enumerate(cover[0]["by_horizon"][:min(len(c["by_horizon"])
                                                              for c in cover)])]}
    stage("inference")
    # 6. online inference on the same held-out trials: the posterior sharpens as frames arrive
    online = online_sharpening(model, held, fractions=(0.25, 0.5, 1.0),
                               n_steps=cfg["infer_steps"], seed=seed)
    summary["online"] = {k: online[k] for k in ("fractions", "mean_coordinate_entropy",
                                                "mean_label_entropy", "accuracy",
                                                "entropy_decreases")}
    stage("online")
    summary["stage_seconds"] = stages
    summary["seconds_total"] = time.perf_counter() - t_all
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, default=float))
    sections = [
        ("MAP fit", [out / "fit_trace.png", f"<p>{d['seconds']:.1f} s, "
                     f"{html.escape(convergence_note(d))}."
                     + (f" The {'quick' if quick else 'full'} demo stops its fit at "
                        f"{cfg['max_iter']} iterations to keep to its time budget; the "
                        f"generated handshakes and the posterior below are those of this fit."
                        if d.get("convergence", {}).get("max_iter_reached") else "")
                     + "</p>"]),
        ("Posterior (emcee)" + (": hyperparameters, style vectors held at the MAP"
                                if cfg["fix_styles"] else ""),
         [f"<p>{html.escape(POSTERIOR_NOTE[cfg['fix_styles']].format(ndim=post.target.ndim))}"
          f"</p>", out / "trace.png", table(
            [[k, f"{v:.3g}" if isinstance(v, float) else v]
             for k, v in summary["posterior"].items()], ["quantity", "value"])]),
        ("Generated handshakes", [viewer_fragment(clips, note=(
            "Emotions: posterior-predictive rollouts (faint skeletons: sampled rollouts; discs: "
            "mean +- 2 sd of each joint's position, the GP variance plus the spread across "
            "posterior draws). Interpolation: the MAP model's mean rollout at each weight. "
            "Animated GIFs of the emotions lie beside this report: "
            f"{', '.join(g.name for g in gifs)}."))]),
        ("Interpolation neutral -> happy, inferred back", [out / "interpolation.png"]),
        ("Emotion inference on held-out trials", [table(
            rows, ["trial", "intended", "inferred", "mean coordinates",
                   "90% highest-density region covers truth", "90% ellipsoid covers truth",
                   "90% intervals cover truth"]),
            table([[levels[i]] + [f"{x:.0f}" for x in C[i]] for i in range(len(levels))],
                  ["inferred \\ intended"] + levels)]),
        ("Online inference on held-out trials (frames arriving)", [table(
            [[f"{f:.0%}", f"{h:.2f}", f"{e:.2f}", f"{a:.0%}"]
             for f, h, e, a in zip(online["fractions"], online["mean_coordinate_entropy"],
                                   online["mean_label_entropy"], online["accuracy"],
                                   strict=True)],
            ["frames seen", "coordinate entropy (nats)", "label entropy (nats)", "correct"])]),
    ]
    write_report(out / "report.html", "bayesmotion demo", sections, summary)
    return summary


def _hand_distance(r) -> float | None:
    sk = r.skeletons[0]
    if r.positions.shape[0] != 2 or "RightHand" not in sk.names:
        return None
    j = sk.index("RightHand")
    return float(np.min(np.linalg.norm(r.positions[0, :, j] - r.positions[1, :, j], axis=-1)))
