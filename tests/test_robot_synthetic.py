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
    t = synthesize(chain, n_frames=40, noise_px=0.0, seed=1, camera="static")
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
    a = synthesize(chain, n_frames=30, noise_px=2.0, drop=0.2, seed=3, camera="static")
    b = synthesize(chain, n_frames=30, noise_px=2.0, drop=0.2, seed=3, camera="static")
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
    t = synthesize(chain, n_frames=40, noise_px=0.0, seed=4, trajectory="milling", camera="static")
    tip = t.positions[:, chain.joint_index("tool_tip")]
    assert np.ptp(tip[:, 2]) < 1e-6  # a horizontal plane
    assert np.ptp(tip[:, 0]) > 0.2 or np.ptp(tip[:, 1]) > 0.2  # a contour of some size


@pytest.mark.parametrize("kw", [dict(camera="drone"), dict(trajectory="dance"), dict(n_frames=1),
                                dict(drop=1.0), dict(noise_px=-1.0), dict(joint_range="all")])
def test_bad_options(chain, kw):
    with pytest.raises(ChainspaceError):
        synthesize(chain, **{"camera": "static", **kw})


def test_default_camera_is_a_realistic_static_pinhole(chain):
    # a phone or an industrial camera, drawn by seed; every point inside the image; some with distortion
    kinds = set()
    for seed in range(6):
        t = synthesize(chain, n_frames=10, noise_px=0.0, seed=seed)
        w, h = t.image_size
        f = t.intrinsics.K[0, 0]
        assert 6 / 11.3 * w - 1e-9 <= f <= 12 / 11.3 * w + 1e-9  # phone 0.8-1.2 w; 6-12 mm lens on 11.3 mm
        assert (t.tracks >= 0).all() and (t.tracks[..., 0] <= w).all() and (t.tracks[..., 1] <= h).all()
        depth = (t.positions @ t.camera_R.T + t.camera_t)[..., 2]
        reach = RobotKinematics(str(URDF), chain).reach()
        assert depth.min() > 0.5 * reach
        kinds.add(bool(t.intrinsics.has_distortion))
    assert kinds == {True, False}


def test_full_joint_range_goes_beyond_the_comfort_window(chain):
    robot = RobotKinematics(str(URDF), chain)
    span = {r: np.ptp(synthesize(chain, n_frames=200, seed=9, camera="static", joint_range=r).q, axis=0)
            for r in ("comfort", "full")}
    width = robot.upper_v - robot.lower_v
    assert (span["comfort"] <= 0.8 * np.pi + 1e-9).all()  # 72 degrees either side of rest at most
    assert (span["full"] > 0.8 * np.pi).any() and (span["full"] <= width + 1e-9).all()


def test_singular_trajectory_passes_through_a_singularity(chain):
    from chainspace.synthetic.robot import conditioning

    robot = RobotKinematics(str(URDF), chain)
    t = synthesize(chain, n_frames=30, noise_px=0.0, seed=2, camera="static", trajectory="singular")
    c = conditioning(robot, t.q)
    assert c[15] < 0.05 * np.median(conditioning(robot, synthesize(chain, n_frames=30, seed=2,
                                                                      camera="static").q))


def test_camera_below_the_base_plane(chain):
    t = synthesize(chain, n_frames=10, noise_px=0.0, seed=1, elevation_deg=-20.0)
    centre = -t.camera_R.T @ t.camera_t  # camera centre in the base frame
    assert centre[2] < t.positions[..., 2].mean()
