import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from chainspace import KinematicChain, TrackError
from chainspace.metrics import bone_length_stats, error_3d, mpjpe, per_frame_error, procrustes_align


def _poses(F=5, J=7, seed=0):
    return np.random.default_rng(seed).normal(size=(F, J, 3))


def test_mpjpe_known_value():
    a = np.zeros((2, 3, 3))
    b = a.copy()
    b[..., 0] = 3.0
    b[..., 1] = 4.0
    assert mpjpe(a, b) == pytest.approx(5.0)


def test_rigid_alignment_removes_rotation_and_translation():
    T = _poses()
    R = Rotation.random(5, random_state=1).as_matrix()
    P = np.einsum("fij,fkj->fki", R, T) + np.array([1.0, -2.0, 3.0])
    assert mpjpe(P, T) > 0.5
    assert error_3d(P, T) < 1e-10
    np.testing.assert_allclose(procrustes_align(P, T), T, atol=1e-10)


def test_scale_only_removed_with_similarity():
    T = _poses()
    P = 1.5 * T
    assert error_3d(P, T) > 0.1
    assert error_3d(P, T, scale=True) < 1e-10


def test_reflection_needs_the_flag():
    T = _poses()
    P = T * np.array([1.0, 1.0, -1.0])
    assert error_3d(P, T) > 0.1
    assert error_3d(P, T, reflection=True) < 1e-10


def test_nan_joints_are_left_out():
    T = _poses()
    P = T.copy() + 0.0
    P[0, 2] = np.nan
    P[1, :] = T[1] + 10.0  # pure translation: aligned away
    e = per_frame_error(P, T)
    assert np.all(e < 1e-10)
    assert np.isnan(procrustes_align(P, T)[0, 2]).all()


def test_single_pose_and_bad_shapes():
    T = _poses(F=1)[0]
    assert error_3d(T + 1.0, T) < 1e-12
    with pytest.raises(TrackError):
        error_3d(np.zeros((3, 4, 3)), np.zeros((3, 5, 3)))


def test_bone_length_stats():
    chain = KinematicChain(["a", "b", "c"], [("a", "b"), ("b", "c")])
    X = np.zeros((4, 3, 3))
    X[:, 1, 0] = 1.0
    X[:, 2, 0] = 1.0 + np.array([1.0, 2.0, 3.0, 2.0])
    st = bone_length_stats(chain, X)
    np.testing.assert_allclose(st["mean"], [1.0, 2.0])
    np.testing.assert_allclose(st["std"], [0.0, np.std([1, 2, 3, 2])])
    assert st["cv"][0] == 0.0
