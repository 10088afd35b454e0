"""What a chain file that is never half-written costs: saving steps with bayesmotion's
``ChainFile`` (each commit writes a copy of the file and replaces it, steps committed in
batches) against emcee's ``HDFBackend`` (each step written in place, which a kill inside the
write leaves unreadable), in the same run.

For each chain size (steps x walkers x coordinates) a file is first filled to all but its last
``timed`` steps, then the last steps are saved with each backend on its own copy of that file,
with a sleep of ``step_s`` between saves standing for the sampler's step (0: saving alone). The
rows give the wall time per step spent saving (the step's own time taken out), the overhead
against the sleeps, the cost of one commit (``ChainFile`` committing every step) and the
largest number of steps a kill could have lost (held in memory, not yet committed). The
largest size is the built-in handshakes' default run (2,000 steps, 54 walkers, 26 coordinates);
0.068 s per step is the default emcee step of that run on one H200 (issue #37's table), the
fastest step the package has measured.

Current result (``results/chain_file.json``): see ``["headline"]`` and ``docs/results.md``.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

SETTINGS = {"full": {"sizes": [[400, 8, 2], [2000, 54, 26], [6000, 54, 26]],
                     "step_s": [0.0, 0.068], "timed": 60},
            "quick": {"sizes": [[400, 8, 2], [2000, 54, 26]], "step_s": [0.0, 0.068],
                      "timed": 20}}


def _states(n: int, W: int, D: int, seed: int):
    import emcee
    import numpy as np

    rng = np.random.default_rng(seed)
    return [emcee.State(rng.normal(size=(W, D)), log_prob=rng.normal(size=W),
                        random_state=np.random.RandomState(seed + i).get_state())
            for i in range(n)]


def _filled(path: Path, L: int, W: int, D: int, timed: int) -> None:
    """A chain file of ``L`` planned steps holding all but the last ``timed``."""
    import numpy as np

    from bayesmotion.inference import chainfile

    be = chainfile.ChainFile(str(path))
    be.reset(W, D)
    be.grow(L, None)
    with chainfile.write_h5(path) as f:  # the stored steps in one write
        g, n = f["mcmc"], L - timed
        rng = np.random.default_rng(0)
        g["chain"][:n] = rng.normal(size=(n, W, D))
        g["log_prob"][:n] = rng.normal(size=(n, W))
        for i, v in enumerate(np.random.RandomState(0).get_state()):
            g.attrs[f"random_state_{i}"] = v
        g.attrs["iteration"] = n


def _time(backend, states, step_s: float) -> dict:
    import numpy as np

    from bayesmotion.inference.chainfile import ChainFile

    accepted = np.ones(len(states[0].log_prob), dtype=bool)
    most_held, saving = 0, 0.0
    t0 = time.perf_counter()
    for s in states:
        if step_s:
            time.sleep(step_s)
        t = time.perf_counter()
        backend.save_step(s, accepted)
        saving += time.perf_counter() - t
        if isinstance(backend, ChainFile):
            most_held = max(most_held, len(backend._pending))
    t = time.perf_counter()
    if isinstance(backend, ChainFile):
        backend.commit()  # what the runner does when it stops
    saving += time.perf_counter() - t
    wall = time.perf_counter() - t0
    n = len(states)
    return {"save_ms_per_step": 1e3 * saving / n,
            "overhead": saving / (n * step_s) if step_s else None,
            "wall_s": wall, "most_steps_held": most_held}


def run(quick: bool) -> dict:
    import emcee
    from _common import headline

    from bayesmotion.inference import chainfile

    settings = SETTINGS["quick" if quick else "full"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for L, W, D in settings["sizes"]:
            base = tmp / f"base_{L}_{W}_{D}.h5"
            _filled(base, L, W, D, settings["timed"])
            states = _states(settings["timed"], W, D, seed=L)
            for step_s in settings["step_s"]:
                row = {"steps": L, "walkers": W, "coordinates": D, "step_s": step_s,
                       "file_mb": base.stat().st_size / 2**20}
                for name in ("emcee_in_place", "chainfile_batched", "chainfile_every_step"):
                    path = tmp / f"{name}.h5"
                    shutil.copyfile(base, path)
                    if name == "emcee_in_place":
                        be = emcee.backends.HDFBackend(str(path))
                    else:
                        be = chainfile.ChainFile(str(path))
                    be.grow(len(states), None)  # as emcee's sampler does before its steps
                    ratio = chainfile.COMMIT_RATIO
                    if name == "chainfile_every_step":
                        chainfile.COMMIT_RATIO = 0.0
                    try:
                        row[name] = _time(be, states, step_s)
                    finally:
                        chainfile.COMMIT_RATIO = ratio
                    full = emcee.backends.HDFBackend(str(path), read_only=True)
                    assert full.iteration == L, (name, full.iteration, L)
                rows.append(row)
    big = [2000, 54, 26]  # the built-in handshakes' default run
    fast = [r for r in rows if [r["steps"], r["walkers"], r["coordinates"]] == big
            and r["step_s"] == 0.068][0]
    over = fast["chainfile_batched"]["overhead"]
    allowed = fast["emcee_in_place"]["overhead"] + 1 / chainfile.COMMIT_RATIO
    return {
        "settings": {**settings, "commit_ratio": chainfile.COMMIT_RATIO},
        "rows": rows,
        "headline": [
            headline(f"chain file saving at {big[0]} x {big[1]} x {big[2]}, 0.068 s steps: "
                     f"overhead of the never-half-written file", round(100 * over, 2), "%",
                     f"<= emcee in place + 1 / COMMIT_RATIO ({100 * allowed:.1f}%)",
                     bool(over <= allowed),
                     f"emcee in place {100 * fast['emcee_in_place']['overhead']:.2f}%; "
                     f"a commit {fast['chainfile_every_step']['save_ms_per_step']:.1f} ms; "
                     f"at most {fast['chainfile_batched']['most_steps_held']} steps held"),
        ],
    }
