"""Synthetic robot footage: trajectories inside the limits, the camera, noise and drops."""

from pathlib import Path

import numpy as np
import pytest

from chainspace.errors import ChainspaceError
from chainspace.robot.kinematics import RobotKinematics
from chainspace.synthetic.robot import synthesize
from chainspace.io.urdf import from_urdf

URDF = Path(__file__).resolve().parents[1] / "robots" / "milling_arm.urdf"


@pytest.fixture(scope="module")
def chain():
    return from_urdf(URDF)


def test_random_trial_shapes_limits_and_projection(chain):
    t = synthesize(chain, n_frames=40, noise_px=0.0, seed=1)
    robot = RobotKinematics(URDF, chain)
    assert t.q.shape == (40, robot.nq) and t.tracks.shape == (40, chain.n_joints, 2)
    assert (t.q[:, robot.limited] >= robot.lower[robot.limited]).all()
    assert (t.q[:, robot.limited] <= robot.upper[robot.limited]).all()
    assert np.allclose(t.positions, robot.positions(t.q))
    # a static camera with orthogonal rows of equal norm, and tracks = P X + t
    assert np.allclose(t.cameras, t.cameras[0])
    P = t.cameras[0]
    assert abs(P[0] @ P[1]) < 1e-9 * (P[0] @ P[0]) and np.isclose(P[0] @ P[0], P[1] @ P[1])
    assert np.allclose(t.tracks, t.positions @ P.T + t.translations[:, None])
    # the robot spans about image_height_px
    extent = max(np.ptp(t.tracks[..., 0]), np.ptp(t.tracks[..., 1]))
    assert extent == pytest.approx(800.0, rel=1e-6)
    # smooth: joint steps between frames are small
    assert np.abs(np.diff(t.q, axis=0)).max() < 0.1


def test_noise_drop_and_seed(chain):
    a = synthesize(chain, n_frames=30, noise_px=2.0, drop=0.2, seed=3)
    b = synthesize(chain, n_frames=30, noise_px=2.0, drop=0.2, seed=3)
    assert np.array_equal(np.isnan(a.tracks), np.isnan(b.tracks))
    assert np.allclose(np.nan_to_num(a.tracks), np.nan_to_num(b.tracks))
    gone = np.isnan(a.tracks).any(-1)
    assert 0.1 < gone.mean() < 0.3 and (a.confidence[gone] == 0).all() and (a.confidence[~gone] == 1).all()
    clean = a.positions @ a.cameras[0].T + a.translations[:, None]
    err = (a.tracks - clean)[~gone]
    assert 1.6 < err.std() < 2.4


def test_moving_camera(chain):
    t = synthesize(chain, n_frames=20, camera="moving", noise_px=0.0, seed=2)
    assert not np.allclose(t.cameras[0], t.cameras[-1])


def test_milling_trajectory_traces_a_horizontal_contour(chain):
    t = synthesize(chain, n_frames=40, noise_px=0.0, seed=4, trajectory="milling")
    tip = t.positions[:, chain.joint_index("tool_tip")]
    assert np.ptp(tip[:, 2]) < 1e-6  # a horizontal plane
    assert np.ptp(tip[:, 0]) > 0.2 or np.ptp(tip[:, 1]) > 0.2  # a contour of some size


@pytest.mark.parametrize("kw", [dict(camera="drone"), dict(trajectory="dance"), dict(n_frames=1),
                                dict(drop=1.0), dict(noise_px=-1.0)])
def test_bad_options(chain, kw):
    with pytest.raises(ChainspaceError):
        synthesize(chain, **kw)
