"""Online inference with every prefix padded as the whole clip (``infer_emotion(pad_to=)``)
against each prefix padded to its own length, in fresh processes.

    python benchmarks/online_padding.py [--quick]

The model is the quick demo's: ``HGPDM()`` fitted by MAP on the built-in handshakes at 10 fps
without the four held-out trials (``max_iter`` as the quick demo). Each row is a fresh Python
process (compilation is per process) that loads the model and runs either the demo's online
section, ``online_sharpening(model, held, fractions=(0.25, 0.5, 1.0), n_steps=150)``, or
``infer_online`` over one held-out trial (``step=3``), each two ways:

* ``own_length``: ``pad_to=None``, each prefix padded to :func:`bayesmotion.shapes.padded_length`
  of its own frames (one compilation per padded length);
* ``whole_clip``: the default of both functions, every prefix padded as the whole trial.

The answers should agree to the projection's tolerance (the padded frames are masked out of
the density, but the projection's diagonal scaling sees more coordinates, so the iterates
differ): the headline checks that every prefix gets the same label (``infer_online``) or the
same right/wrong verdict (``online_sharpening``), and reports the largest difference in the
coordinates' differential entropy, in nats.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import headline, standalone_main  # noqa: E402

NAME = "online_padding"
FULL = {"fps": 10.0, "max_iter": 150, "n_steps": 150, "fractions": [0.25, 0.5, 1.0], "step": 3}
QUICK = {"fps": 10.0, "max_iter": 20, "n_steps": 60, "fractions": [0.5, 1.0], "step": 6}
WAYS = ("own_length", "whole_clip")

# one process: load the model, run the online section, print timings and answers as JSON
PROCESS = r"""
import json, sys, time
import bayesmotion
from bayesmotion.app.demo import _split
from bayesmotion.datasets import load_handshakes
from bayesmotion.evaluation.evaluate import online_sharpening
from bayesmotion.shapes import padded_length
model_path, fps, n_steps, fractions, step, what, way = sys.argv[1:]
fps, n_steps, step = float(fps), int(n_steps), int(step)
pad = {"pad_to": None} if way == "own_length" else {}
model = bayesmotion.load(model_path)
held = _split(load_handshakes(fps=fps))[1]
t = time.perf_counter()
if what == "sharpening":
    res = online_sharpening(model, held, fractions=json.loads(fractions), n_steps=n_steps,
                            seed=0, **pad)
    rows = [p for tr in res["trials"] for p in tr["prefixes"]]
    out = {"prefix_frames": sorted({p["frames"] for p in rows}),
           "correct": [bool(p["correct"]) for p in rows],
           "coordinate_entropy": [p["coordinate_entropy"] for p in rows],
           "mean_coordinate_entropy": res["mean_coordinate_entropy"],
           "mean_label_entropy": res["mean_label_entropy"], "accuracy": res["accuracy"]}
else:
    trial = held[0]
    eps = list(bayesmotion.infer_online(model, trial, step=step, couple=trial.labels["couple"],
                                        n_steps=n_steps, latent_uncertainty=False, seed=0,
                                        **pad))
    out = {"prefix_frames": [e.info["n_frames"] for e in eps],
           "padded_frames": [e.info["padded_frames"] for e in eps],
           "labels": [e.label for e in eps],
           "coordinate_entropy": [e.coordinate_entropy for e in eps]}
print(json.dumps({"seconds": time.perf_counter() - t, **out}))
"""


def _process(model: Path, cfg: dict, what: str, way: str) -> dict:
    env = {**os.environ, "BAYESMOTION_COMPILE_CACHE": "off"}
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", PROCESS, str(model), str(cfg["fps"]),
                        str(cfg["n_steps"]), json.dumps(cfg["fractions"]), str(cfg["step"]),
                        what, way], env=env, capture_output=True, text=True, check=True)
    return {**json.loads(r.stdout.strip().splitlines()[-1]),
            "process_seconds": time.perf_counter() - t}


def _max_difference(a, b) -> float:
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


def run(quick: bool) -> dict:
    from bayesmotion.app.demo import _split
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.model.spec import HGPDM
    from bayesmotion.shapes import padded_length

    cfg = QUICK if quick else FULL
    train, held = _split(load_handshakes(fps=cfg["fps"]))
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "model.npz"
        HGPDM().fit(train, max_iter=cfg["max_iter"], progress=False).save(model)
        runs = {what: {way: _process(model, cfg, what, way) for way in WAYS}
                for what in ("sharpening", "online")}
    sharp, online = runs["sharpening"], runs["online"]
    agree = (sharp["own_length"]["correct"] == sharp["whole_clip"]["correct"]
             and online["own_length"]["labels"] == online["whole_clip"]["labels"])
    entropy_gap = max(_max_difference(runs[w]["own_length"]["coordinate_entropy"],
                                      runs[w]["whole_clip"]["coordinate_entropy"])
                      for w in runs)
    whole = padded_length(held[0].n_frames)
    rows = []
    for what, label in (("sharpening", "online_sharpening (the demo's online section, "
                                       f"{len(held)} trials)"),
                        ("online", f"infer_online over one trial "
                                   f"({len(online['whole_clip']['prefix_frames'])} prefixes)")):
        own = sorted({padded_length(k) for k in runs[what]["own_length"]["prefix_frames"]})
        rows += [headline(f"{label}, fresh process: each prefix padded to its own length",
                          runs[what]["own_length"]["seconds"], "s",
                          note=f"padded lengths {own}"),
                 headline(f"{label}, fresh process: every prefix padded as the whole trial",
                          runs[what]["whole_clip"]["seconds"], "s",
                          note=f"padded length {whole}")]
    rows += [headline("every prefix: the same label (infer_online) and the same right/wrong "
                      "verdict (online_sharpening)", agree, "", "True", agree),
             headline("largest difference in a prefix's coordinate entropy", entropy_gap,
                      "nats")]
    return {"settings": {**cfg, "n_train_trials": len(train), "held_out": len(held),
                         "frames_per_trial": held[0].n_frames},
            "runs": runs, "headline": rows}


def main() -> int:
    return standalone_main(NAME, run, __doc__, "a barely fitted model, fewer steps",
                           lambda r: "\n".join(map(str, r["headline"])))


if __name__ == "__main__":
    sys.exit(main())
