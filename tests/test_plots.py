"""Sanity views: what is drawn where (Y up, equal axes, bones from parents, hidden joints),
files written atomically and decodable, GIF frame counts and timing."""

import os

import numpy as np
import pytest
from matplotlib import animation
from matplotlib.image import imread
from mpl_toolkits.mplot3d.art3d import Line3DCollection
from PIL import Image

import bayesmotion as bm
from bayesmotion.errors import BayesmotionError
from bayesmotion.viz.animate import animate
from bayesmotion.viz.plots import plot_bands, plot_pose, to_plot

PARENTS = (-1, 0, 1, 0, 0)  # hips, spine, head, left leg, right leg


def stick_positions(T=5):
    """(T, 5, 3) a figure standing on Y, drifting along X (every frame differs)."""
    base = np.array([[0, 10, 0], [0, 15, 0], [0, 20, 0], [-2, 0, 0], [2, 0, 1]], float)
    return base[None] + np.arange(T)[:, None, None] * np.array([1.0, 0, 0])


def skeleton(root):
    """5 joints (root with 6 channels, others 3), an End Site on the head."""
    return bm.Skeleton([root, "spine", "head", "lleg", "rleg"], PARENTS,
                       [[0, 0, 0], [0, 5, 0], [0, 5, 0], [-2, -10, 0], [2, -10, 0]],
                       [("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                         "Yrotation")] + [("Zrotation", "Xrotation", "Yrotation")] * 4,
                       {2: [0, 3, 0]})


SKELETONS = {"hips": skeleton("hips"), "joint_Root": skeleton("joint_Root")}  # one FK compile


def small_motion(name="a", T=5, root="hips", shift=0.0):
    """A motion on :func:`skeleton` walking along X while the spine bends."""
    sk = SKELETONS[root]
    v = np.zeros((T, sk.n_channels))
    v[:, 0] = np.arange(T) + shift
    v[:, 1] = 10
    v[:, 6] = np.linspace(0, 30, T)  # spine bends over time
    return bm.Motion(sk, v, 30.0, name)


def dots(ax):
    """(n, 3) plot coordinates of the joint dots of each solid skeleton."""
    return [np.array(line.get_data_3d()).T for line in ax.lines]


def assert_png(path, shape):
    assert path.stat().st_size > 0
    assert imread(path).shape[:2] == shape


# ------------------------------------------------------------------------------ plot_pose
def test_plot_pose_raw_positions_y_up_and_equal_axes(tmp_path):
    P = stick_positions()
    ax = plot_pose(P, 3, parents=PARENTS, path=tmp_path / "pose.png", dpi=40)
    assert_png(tmp_path / "pose.png", (200, 200))  # 5 x 5 inches at 40 dpi
    (d,) = dots(ax)
    np.testing.assert_allclose(d, to_plot(P[3]))
    np.testing.assert_allclose(d[:, 2], P[3, :, 1])  # data Y is the vertical plot axis
    np.testing.assert_allclose(d[:, 1], -P[3, :, 2])  # a rotation, not a mirror
    spans = [np.diff(lim)[0] for lim in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
    np.testing.assert_allclose(spans, spans[0])
    assert ax.get_zlim()[0] <= 0 and ax.get_zlim()[1] >= 20
    (bones,) = [c for c in ax.collections if isinstance(c, Line3DCollection)]
    assert len(bones.get_segments()) == 4  # one per non-root joint
    assert ax.get_title() == "frame 3"


def test_plot_pose_trial_two_actors_end_sites_and_hidden_root():
    a, b = small_motion("a"), small_motion("b", shift=20.0)
    ax = plot_pose(bm.Trial((a, b)), 2, end_sites=True)
    d_a, d_b = dots(ax)
    assert len(d_a) == 6  # 5 joints + 1 End Site
    np.testing.assert_allclose(d_a, to_plot(a.positions(with_end_sites=True)[2]), atol=1e-12)
    np.testing.assert_allclose(d_b[:, 0] - d_a[:, 0], 20.0)
    assert ax.lines[0].get_color() != ax.lines[1].get_color()
    # Bandai's fixed joint_Root is hidden by default, with its bones
    ax = plot_pose(small_motion(root="joint_Root"), 0)
    assert len(dots(ax)[0]) == 4
    ax.figure.canvas.draw()  # 3-D segments are projected when drawn
    assert len(ax.collections[0].get_segments()) == 1  # head-spine; the root's three bones go


def test_plot_pose_spread_drawn_faintly():
    P = stick_positions()
    samples = P[None] + np.random.default_rng(0).normal(0, 0.1, (3,) + P.shape)
    ax = plot_pose(P, 0, parents=PARENTS, spread=samples)
    faint = [c for c in ax.collections if c.get_alpha() is not None and c.get_alpha() < 1]
    assert len(faint) == 3 and len(dots(ax)) == 1


def test_plot_pose_errors():
    P = stick_positions()
    with pytest.raises(BayesmotionError, match="need `parents`"):
        plot_pose(P, 0)
    with pytest.raises(BayesmotionError, match="parents must give one index"):
        plot_pose(P, 0, parents=(-1, 0, 1))
    with pytest.raises(BayesmotionError, match="frame 9 is out of range for 5 frames"):
        plot_pose(P, 9, parents=PARENTS)
    with pytest.raises(BayesmotionError, match=r"positions must be .* got \(5, 5, 2\)"):
        plot_pose(P[..., :2], 0, parents=PARENTS)
    with pytest.raises(BayesmotionError, match="cannot save a figure as 'x.xyz'"):
        plot_pose(P, 0, parents=PARENTS, path="x.xyz")


def test_saving_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "pose.png"
    plot_pose(stick_positions(), 0, parents=PARENTS, path=path, dpi=20)
    before = path.read_bytes()

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        plot_pose(stick_positions(), 4, parents=PARENTS, path=path, dpi=30)
    with pytest.raises(OSError, match="disk full"):
        animate(stick_positions(), tmp_path / "pose.gif", fps=5, parents=PARENTS, dpi=20)
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["pose.png"]


# -------------------------------------------------------------------------------- animate
def test_animate_gif_frames_and_timing(tmp_path):
    out = animate(stick_positions(7), tmp_path / "a.gif", fps=10, stride=2, parents=PARENTS,
                  spread=[stick_positions(7) + 0.5], figsize=(2, 2), dpi=30)
    assert out == tmp_path / "a.gif" and out.stat().st_size > 0
    with Image.open(out) as im:
        assert im.format == "GIF" and im.size == (60, 60)
        assert im.n_frames == 4  # frames 0, 2, 4, 6
        assert im.info["duration"] == 100  # ms per image at 10 fps


def test_animate_trial_defaults_to_real_time(tmp_path):
    trial = bm.Trial((small_motion("a", T=6), small_motion("b", T=6, shift=5.0)))
    out = animate(trial, tmp_path / "t.gif", stride=3, title="two", figsize=(2, 2), dpi=30)
    with Image.open(out) as im:
        assert im.n_frames == 2
        assert im.info["duration"] == 100  # 30 fps / stride 3 = 10 images per second


def test_animate_errors(tmp_path, monkeypatch):
    P = stick_positions()
    with pytest.raises(BayesmotionError, match="raw positions have no frame rate; pass fps="):
        animate(P, tmp_path / "a.gif", parents=PARENTS)
    with pytest.raises(BayesmotionError, match=r"same number of frames, got \[4, 5\]"):
        animate(P, tmp_path / "a.gif", fps=5, parents=PARENTS, spread=P[:4])
    with pytest.raises(BayesmotionError, match="stride must be a positive int"):
        animate(P, tmp_path / "a.gif", fps=5, parents=PARENTS, stride=0)
    with pytest.raises(BayesmotionError, match="animations are .gif or .mp4, not '.avi'"):
        animate(P, tmp_path / "a.avi", fps=5, parents=PARENTS)
    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    with pytest.raises(BayesmotionError, match="MP4 needs ffmpeg on PATH"):
        animate(P, tmp_path / "a.mp4", fps=5, parents=PARENTS)
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- plot_bands
def test_plot_bands_draws_mean_plus_minus_two_sd(tmp_path):
    t = np.linspace(0, 1, 11)
    mean = np.stack([np.sin(t), np.cos(t)], axis=1)
    sd = np.stack([0.1 + 0 * t, 0.2 * t], axis=1)
    ax = plot_bands(t, mean, sd, ["hand x", "hand y"], tmp_path / "b.png", dpi=30)
    assert_png(tmp_path / "b.png", (105, 180))  # 6 x 3.5 inches at 30 dpi
    for c, band in enumerate(ax.collections):
        y = band.get_paths()[0].vertices[:, 1]
        np.testing.assert_allclose([y.min(), y.max()], [(mean[:, c] - 2 * sd[:, c]).min(),
                                                        (mean[:, c] + 2 * sd[:, c]).max()])
    np.testing.assert_allclose(ax.lines[1].get_ydata(), mean[:, 1])
    assert [x.get_text() for x in ax.get_legend().get_texts()] == ["hand x", "hand y"]


def test_plot_bands_errors():
    t = np.arange(4.0)
    with pytest.raises(BayesmotionError, match="needs t \\(T,\\), mean and sd \\(T, K\\)"):
        plot_bands(t, np.zeros((4, 2)), np.zeros((4, 2)), ["one"])
    with pytest.raises(BayesmotionError, match="sd finite and >= 0"):
        plot_bands(t, np.zeros(4), -np.ones(4), ["x"])


# ------------------------------------------------------------------------------ real data
def test_real_bandai_pose_upright(bandai_files):
    m = bm.read_bvh(bandai_files[0])
    ax = plot_pose(m, 0)
    (d,) = dots(ax)
    names = [n for n in m.skeleton.names if n != "joint_Root"]
    head, toe = d[names.index("Head"), 2], d[names.index("Toes_L"), 2]
    assert head - toe > 100  # standing, Y up, in cm


def test_spread_samples_hide_what_their_actor_hides_and_take_its_colour():
    """Sample arrays do not draw Bandai's static joint_Root (a bone from the world origin to
    the hips), and each sample takes its own actor's colour."""
    from bayesmotion.viz.plots import scene, spread_colors

    a, b = small_motion("a", root="joint_Root"), small_motion("b", root="joint_Root", shift=5)
    P = np.stack([a.positions(), b.positions()])  # (A, T, J, 3)
    S = np.stack([P + 0.01 * k for k in range(3)])  # (S, A, T, J, 3)
    main, extra = scene([a, b], spread=S.reshape(-1, *S.shape[2:]))
    assert main[0].hidden and all(t.hidden == main[0].hidden for t in extra)
    cols = spread_colors(len(main), len(extra), ["blue", "red"])
    assert cols == ["blue", "red"] * 3
    for k, t in enumerate(extra):  # track k is sample k // 2 of actor k % 2
        np.testing.assert_array_equal(t.source, S[k // 2, k % 2])


def test_plot_reliability_draws_each_bin_with_its_consistency_bar(tmp_path):
    from bayesmotion.evaluation.calibration import calibration_consistency
    from bayesmotion.viz.calibration import plot_reliability

    rng = np.random.default_rng(0)
    p = rng.dirichlet(np.ones(4) * 0.5, 40)
    truth = np.array([rng.choice(4, p=row) for row in p])
    ax = plot_reliability(p, truth, tmp_path / "rel.png", n_draws=500)
    c = calibration_consistency(p, truth, n_draws=500)
    bars = ax.collections[0].get_segments()  # one vertical bar per non-empty bin
    assert len(bars) == len(c["bins"])
    for seg, b in zip(bars, c["bins"], strict=True):
        assert seg[:, 0] == pytest.approx([b["confidence"]] * 2)
        assert seg[:, 1] == pytest.approx(b["accuracy_interval"])
    points = ax.collections[1].get_offsets()
    assert np.asarray(points)[:, 1] == pytest.approx([b["accuracy"] for b in c["bins"]])
    assert f"ECE {c['ece']:.3f}" in ax.get_title()
    assert imread(tmp_path / "rel.png").shape[-1] in (3, 4)
    with pytest.raises(BayesmotionError, match="probabilities"):
        plot_reliability(np.ones((3, 1)), np.zeros(3, int))
