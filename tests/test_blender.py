"""Blender round trip: generated BVH files read by Blender's own importer (``import_anim.bvh``,
run by ``tests/blender_import_bvh.py`` in a background Blender) give back the package's frame
count, frame rate, joint names and forward-kinematics positions.

Conventions, stated once for both tests:

* Axes and scale: the importer is given ``axis_forward="-Z", axis_up="Y"`` (BVH's Y-up frame to
  Blender's Z-up one) and ``global_scale=SCALE``; the package's positions get the same map,
  ``SCALE * p @ C.T`` with ``C = CONVERSION`` (x, y, z) -> (x, -z, y); Blender's own
  ``axis_conversion`` of those arguments is checked to be ``C``, and the positions compared
  below check that the importer applied it.
* Frames: file frame ``t`` (from 0) is keyed at Blender frame ``FRAME_START + t``; the dummy
  rest frame the importer prepends is not keyed.
* Joints: one bone per joint, named as the joint; an End Site is no bone but the tail of its
  joint's bone, so end sites are compared with those tails.
* Tolerance: ``write_bvh`` writes the shortest decimal that reads back to the same float64, so
  the text loses nothing; Blender then keeps keyframes and pose matrices in float32. A bone's
  world position is a chain of up to ten float32 rotations and additions, each off by about one
  float32 unit in the last place of the largest coordinate, so positions are compared to
  ``32 * eps32 * extent`` (extent: the largest |coordinate|); the errors measured are about 3 eps32
  units of extent, and one frame of offset is thousands of times the tolerance (checked).
"""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.data import Motion, MotionDataset, Trial
from tests.conftest import make_tiny_dataset, synthetic_walk

SCRIPT = Path(__file__).with_name("blender_import_bvh.py")
FRAME_START = 10  # not Blender's default 1, so an ignored or off-by-one start shows
SCALE = 0.5  # not 1, so a scale applied twice or not at all shows
CONVERSION = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # BVH (x, y, z) -> Blender (x, -z, y)
TOL = 32 * np.finfo(np.float32).eps  # relative to the largest |coordinate| (module docstring)


@pytest.fixture(scope="session")  # session: set up, and skipped, before the fitted model
def blender():
    path = shutil.which("blender")
    if path is None:
        pytest.skip("blender not installed: `blender` is not on PATH, so the Blender round trip "
                    "is not checked (Debian/Ubuntu: apt-get install blender)")
    return path


def blender_import(blender: str, paths: list[Path], out: Path) -> dict:
    """What Blender's importer read from each file (see tests/blender_import_bvh.py)."""
    cmd = [blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python",
           str(SCRIPT), "--", str(out), str(FRAME_START), repr(SCALE), *map(str, paths)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"blender exit {r.returncode}:\n{r.stdout[-3000:]}{r.stderr[-3000:]}"
    return json.loads(out.read_text())


def check_round_trip(motion: Motion, read: dict) -> None:
    """Blender's reading of ``motion``'s BVH file against the package's own values."""
    sk, T, J = motion.skeleton, motion.n_frames, motion.skeleton.n_joints
    # joints: one bone per joint, same names and tree, no bone for an End Site
    assert read["bones"] == list(sk.names) == read["pose_bones"]
    assert read["parents"] == [sk.names[p] if p >= 0 else None for p in sk.parents]
    # frame rate: Blender keeps an integer fps and a float32 fps_base
    assert read["fps"] == round(motion.fps)
    assert read["fps"] / read["fps_base"] == pytest.approx(motion.fps, rel=1e-6)
    # frames: every F-curve keys the T file frames at FRAME_START ... FRAME_START + T - 1
    keys = np.arange(FRAME_START, FRAME_START + T, dtype=float)
    assert read["action_frames"] == [keys[0], keys[-1]]
    assert read["keyframes"] and all(np.array_equal(k, keys) for k in read["keyframes"].values())
    assert read["scene_frames"][0] == FRAME_START and read["scene_frames"][1] >= keys[-1]
    # positions: every joint at every frame (root, hands, feet and head among them)
    np.testing.assert_array_equal(np.array(read["conversion"])[:3, :3], CONVERSION)
    P = SCALE * motion.positions(with_end_sites=True) @ CONVERSION.T  # (T, J + E, 3)
    heads, tails = np.array(read["heads"]), np.array(read["tails"])
    assert heads.shape == (T, J, 3)
    atol = TOL * np.abs(P).max()
    np.testing.assert_allclose(heads, P[:, :J], rtol=0, atol=atol)
    assert np.abs(heads[1:] - P[:-1, :J]).max() > 1000 * atol  # a frame off would show
    # End Sites: the tails of their joints' bones (the importer lengthens a tail under 0.001)
    ends = sorted(sk.end_sites)
    kept = [k for k, j in enumerate(ends) if SCALE * np.linalg.norm(sk.end_sites[j]) > 0.01]
    assert kept
    np.testing.assert_allclose(tails[:, [ends[k] for k in kept]], P[:, J:][:, kept], rtol=0,
                               atol=atol)


@pytest.mark.slow
def test_blender_reads_a_generated_handshake_as_the_package_does(blender, tiny_model,
                                                                 tmp_path):
    rollout = tiny_model.generate(emotion="happy", n_frames=20)
    paths = rollout.write_bvh(tmp_path)
    read = blender_import(blender, paths, tmp_path / "read.json")
    motions = rollout.to_motion()
    assert len(paths) == len(motions) == 2
    for path, motion in zip(paths, motions, strict=True):
        assert {"Hips", "Head", "LeftHand", "RightFoot"} <= set(motion.skeleton.names)
        check_round_trip(motion, read[str(path)])


@pytest.mark.slow
def test_blender_reads_a_generated_walk_as_the_package_does(blender, tmp_path):
    base = make_tiny_dataset().trials[0].actors[0]  # a standing pose of the CMU rig
    fps = 30.0  # a frame time with no exact decimal: 0.03333333333333333
    clips = {"neutral": synthetic_walk(base, fps, 36, 1.0, 25.0),
             "happy": synthetic_walk(base, fps, 36, 1.25, 35.0)}
    data = MotionDataset(tuple(Trial((m,), {"emotion": e}, e) for e, m in clips.items()),
                         {"emotion": tuple(clips)})
    model = bm.HGPDM(latent_dim=3, interaction_dim=3).fit(data, max_iter=60, progress=False)
    rollout = model.generate(emotion="neutral", n_frames=45)
    (motion,) = rollout.to_motion()
    # the generated motion walks: its hips travel at least half the training clips' pace
    hips = motion.positions()[:, 0]
    pace = np.linalg.norm((hips[-1] - hips[0])[[0, 2]]) / motion.duration
    assert pace > 0.5 * 1.4 * base.positions()[0, 0, 1]
    paths = rollout.write_bvh(tmp_path, prefix="walk")
    read = blender_import(blender, paths, tmp_path / "read.json")
    check_round_trip(motion, read[str(paths[0])])
