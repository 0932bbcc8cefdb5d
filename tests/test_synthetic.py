import numpy as np
import pytest

from chainspace import KinematicChain, TrackError
from chainspace.synthetic.views import observe, orbit_cameras, scale_for_span, swing_motion


@pytest.mark.parametrize("up", ["z", "y"])
def test_orbit_cameras_are_weak_perspective_and_orbit_the_up_axis(up):
    P = orbit_cameras(50, sweep_deg=20.0, elevation_deg=15.0, start_deg=30.0, scale=400.0, up=up, seed=0)
    assert P.shape == (50, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(P, axis=-1), 400.0)
    np.testing.assert_allclose((P[:, 0] * P[:, 1]).sum(-1), 0.0, atol=1e-9)
    u = np.array([0, 0, 1.0]) if up == "z" else np.array([0, 1.0, 0])
    view = np.cross(P[:, 0], P[:, 1]) / 400.0**2  # viewing direction
    # elevation: the view looks down at 15 degrees
    np.testing.assert_allclose(np.degrees(np.arcsin(-view @ u)), 15.0, atol=1e-9)
    # the image x axis stays horizontal (orbit about the up axis)
    np.testing.assert_allclose(P[:, 0] @ u, 0.0, atol=1e-9)
    h = view - np.outer(view @ u, u)
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    sweep = np.degrees(np.arccos(np.clip(h[0] @ h[-1], -1, 1)))
    assert sweep == pytest.approx(20.0, abs=1e-6)


def test_orbit_cameras_seeded_and_random_start():
    a = orbit_cameras(10, seed=3)
    np.testing.assert_array_equal(a, orbit_cameras(10, seed=3))
    assert not np.allclose(a, orbit_cameras(10, seed=4))
    with pytest.raises(TrackError):
        orbit_cameras(10, up="x")


def test_observe_projects_and_adds_noise():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 10, 3))
    P = orbit_cameras(200, scale=100.0, seed=1)
    W = observe(X, P, translations=[5.0, 6.0])
    np.testing.assert_allclose(W, np.einsum("fij,fkj->fki", P, X) + [5.0, 6.0])
    Wn = observe(X, P, translations=[5.0, 6.0], noise_px=2.0, seed=2)
    assert np.std(Wn - W) == pytest.approx(2.0, rel=0.05)
    with pytest.raises(TrackError):
        observe(X, P[:5])


def test_scale_for_span_and_swing_motion_keep_lengths():
    chain = KinematicChain(["r", "a", "b"], [("r", "a"), ("a", "b")], rest_pose=[[0, 0, 0], [0, 0, 1.0], [0, 0, 1.8]])
    X = swing_motion(chain, 60, seed=0)
    L = chain.bone_lengths(X)
    np.testing.assert_allclose(L, np.broadcast_to([1.0, 0.8], L.shape), atol=1e-12)
    assert X.std(axis=0).max() > 0.05
    s = scale_for_span(np.broadcast_to(chain.rest_pose, (3, 3, 3)), 720.0)
    assert s == pytest.approx(400.0)
