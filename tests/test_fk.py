"""Forward kinematics against an independent NumPy/SciPy reference."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import bayesmotion as bm
from bayesmotion.data.fk import forward_kinematics


def reference_fk(skeleton, values):
    """Plain loop over frames and joints; rotations from SciPy (upper-case = intrinsic)."""
    T = values.shape[0]
    out = np.zeros((T, skeleton.n_joints, 3))
    starts = skeleton.channel_offsets
    for t in range(T):
        Rw, pw = {}, {}
        for j, p in enumerate(skeleton.parents):
            chans = skeleton.channels[j]
            vals = values[t, starts[j]:starts[j + 1]]
            rot = [(c[0], v) for c, v in zip(chans, vals, strict=True) if c.endswith("rotation")]
            R = (Rotation.from_euler("".join(a for a, _ in rot), [v for _, v in rot],
                                     degrees=True).as_matrix() if rot else np.eye(3))
            off = skeleton.offsets[j].copy()
            for c, v in zip(chans, vals, strict=True):
                if c.endswith("position"):
                    off["XYZ".index(c[0])] = v
            if p < 0:
                Rw[j], pw[j] = R, off
            else:
                Rw[j], pw[j] = Rw[p] @ R, pw[p] + Rw[p] @ off
            out[t, j] = pw[j]
    return out


def random_skeleton(rng, J=7):
    orders = ["ZYX", "XYZ", "YXZ", "ZXY", "XZY", "YZX"]
    parents = [-1] + [int(rng.integers(0, j)) for j in range(1, J)]
    chans = []
    for j in range(J):
        rot = [f"{a}rotation" for a in orders[rng.integers(6)]]
        pos = ["Xposition", "Yposition", "Zposition"]
        chans.append(tuple(pos + rot) if j == 0 or rng.random() < 0.3 else tuple(rot))
    return bm.Skeleton([f"j{j}" for j in range(J)], parents, rng.normal(size=(J, 3)), chans)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fk_matches_reference_on_random_skeletons(seed):
    rng = np.random.default_rng(seed)
    sk = random_skeleton(rng)
    values = rng.uniform(-180, 180, size=(5, sk.n_channels))
    got = np.asarray(forward_kinematics(sk, values))
    np.testing.assert_allclose(got, reference_fk(sk, values), rtol=1e-10, atol=1e-10)


def test_fk_matches_reference_on_real_cmu(cmu_files):
    m = bm.read_bvh(cmu_files[0])
    sel = m.values[::60]
    np.testing.assert_allclose(m.select(slice(None, None, 60)).positions(),
                               reference_fk(m.skeleton, sel), atol=1e-9)


def test_fk_matches_reference_on_real_bandai(bandai_files):
    m = bm.read_bvh(bandai_files[0])
    sel = m.values[::40]
    np.testing.assert_allclose(m.select(slice(None, None, 40)).positions(),
                               reference_fk(m.skeleton, sel), atol=1e-8)


def test_fk_batched_over_leading_axes_and_end_sites():
    rng = np.random.default_rng(3)
    sk = random_skeleton(rng)
    sk = bm.Skeleton(sk.names, sk.parents, sk.offsets, sk.channels, {6: [0.0, 1.0, 0.0]})
    v = rng.uniform(-90, 90, size=(2, 4, sk.n_channels))
    batched = np.asarray(forward_kinematics(sk, v, with_end_sites=True))
    assert batched.shape == (2, 4, sk.n_joints + 1, 3)
    flat = np.asarray(forward_kinematics(sk, v.reshape(8, -1), with_end_sites=True))
    np.testing.assert_allclose(batched.reshape(8, -1, 3), flat, atol=1e-12)
    np.testing.assert_allclose(batched[..., :-1, :].reshape(8, -1, 3),
                               reference_fk(sk, v.reshape(8, -1)), atol=1e-10)


def test_numpy_and_jax_fk_agree_with_end_sites_and_leading_axes():
    from bayesmotion.data.fk import numpy_positions

    rng = np.random.default_rng(5)
    sk = random_skeleton(rng)
    sk = bm.Skeleton(sk.names, sk.parents, sk.offsets, sk.channels, {4: [0.1, 0.2, 0.3]})
    v = rng.uniform(-180, 180, size=(3, 5, sk.n_channels))
    np.testing.assert_allclose(numpy_positions(sk, v, True),
                               np.asarray(forward_kinematics(sk, v, True)), atol=1e-11)


def test_jax_fk_pads_frames_to_buckets_without_changing_results():
    from bayesmotion.data.fk import _jitted_fk, layout_key

    rng = np.random.default_rng(6)
    sk = random_skeleton(rng)
    v = rng.uniform(-90, 90, size=(13, sk.n_channels))
    full = np.asarray(forward_kinematics(sk, v))
    f = _jitted_fk(layout_key(sk), False)
    before = f._cache_size()
    for n in (9, 10, 11, 12, 13):  # one bucket (16 frames): no new compilation
        np.testing.assert_allclose(np.asarray(forward_kinematics(sk, v[:n])), full[:n],
                                   atol=1e-12)
    assert f._cache_size() - before <= 1


@pytest.mark.parametrize("seed", [0, 1])
def test_analytic_position_variance_equals_the_jacfwd_propagation(seed):
    import jax
    import jax.numpy as jnp

    from bayesmotion.data.fk import fk_function, fk_variance_function

    rng = np.random.default_rng(seed)
    sk = random_skeleton(rng, J=9)
    values = jnp.asarray(rng.uniform(-180, 180, size=(6, sk.n_channels)))
    var = jnp.asarray(rng.uniform(0.0, 4.0, size=values.shape))
    off = jnp.asarray(sk.offsets)
    jac = jax.vmap(jax.jacfwd(fk_function(sk)), in_axes=(0, None))(values, off)  # (T, J, 3, C)
    expected = np.einsum("tjkc,tc->tjk", np.asarray(jac) ** 2, np.asarray(var))
    pos, got = jax.jit(fk_variance_function(sk))(values, var, off)
    np.testing.assert_allclose(np.asarray(pos), reference_fk(sk, np.asarray(values)), atol=1e-10)
    np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-10, atol=1e-12)
    assert np.all(np.asarray(got)[:, 0] > 0)  # the root moves with its position channels


def test_integer_and_float32_channels_give_float64_positions_with_exact_offsets():
    """Integer channel values must not truncate the bone offsets (they are cast to the
    values' dtype inside FK) and float32 must not leak into the positions."""
    import bayesmotion as bm
    from bayesmotion.data.fk import forward_kinematics, numpy_positions

    m = bm.load_handshakes(fps=5.0)[0].actors[0]
    zeros = np.zeros((3, m.skeleton.n_channels))
    ref = numpy_positions(m.skeleton, zeros)
    assert np.abs(ref - np.round(ref)).max() > 0.1  # the offsets are not integers
    for dtype in (np.int64, np.int32, np.float32):
        out = forward_kinematics(m.skeleton, zeros.astype(dtype))
        assert out.dtype == np.float64
        np.testing.assert_allclose(np.asarray(out), ref, rtol=1e-12, atol=1e-12)
