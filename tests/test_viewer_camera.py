"""The camera's frustum in the viewer: where the geometry says, and in the HTML."""

from __future__ import annotations

import importlib
import base64
import re
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from chainspace import CameraError, PinholeCamera
from chainspace.cameras.pose import pose_from_weak
from chainspace.chain import KinematicChain
from chainspace.view.viewer import _extent, _stand, frustum_corners, write_html

umsgpack = pytest.importorskip("umsgpack")

CAMERA = PinholeCamera.from_matrix([[800.0, 0, 330.0], [0, 790.0, 235.0], [0, 0, 1]],
                                   [-0.2, 0.07, 0.001, -0.0005, -0.01], 640, 480)


def _pose(seed=0):
    R = Rotation.random(random_state=seed).as_matrix()
    return R, np.array([0.2, -0.1, 3.0])


def test_frustum_corners_reproject_to_the_image_corners():
    R, t = _pose()
    pts = frustum_corners(CAMERA, (R, t), 0.7)
    assert pts.shape == (5, 3)
    np.testing.assert_allclose(pts[0], -R.T @ t, atol=1e-12)  # the camera's centre
    cam = pts[1:] @ R.T + t
    np.testing.assert_allclose(cam[:, 2], 0.7, atol=1e-12)  # at the asked depth
    np.testing.assert_allclose(CAMERA.project(cam), CAMERA.corners(), atol=1e-6)
    np.testing.assert_allclose(CAMERA.corners(), [[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]])


def test_frustum_rejects_bad_poses():
    with pytest.raises(CameraError, match="rotation"):
        frustum_corners(CAMERA, (2 * np.eye(3), np.zeros(3)), 1.0)
    with pytest.raises(CameraError, match="shapes"):
        frustum_corners(CAMERA, (np.eye(3), np.zeros(2)), 1.0)
    with pytest.raises(CameraError, match="depth"):
        frustum_corners(CAMERA, (np.eye(3), np.zeros(3)), 0.0)
    with pytest.raises(CameraError, match="image size"):
        frustum_corners(PinholeCamera(500.0, 500.0, 10.0, 10.0), (np.eye(3), np.zeros(3)), 1.0)


def test_pose_from_weak_inverts_the_weak_camera():
    R, t = _pose(3)
    centre = np.array([0.1, 0.2, 0.3])
    depth = (R @ centre + t)[2]
    f = 0.5 * (CAMERA.fx + CAMERA.fy)
    s = f / depth
    P = s * R[:2]
    t2d = s * t[:2] + [CAMERA.cx, CAMERA.cy]
    R2, t2 = pose_from_weak(P, t2d, CAMERA, centre)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)



def test_pose_from_weak_inverts_a_stack_of_weak_cameras_on_rays():
    # frames first, camera None: the tracks are rays (f = 1, c = 0), as the human pipeline uses it
    poses = [_pose(k) for k in range(4)]
    R = np.stack([p[0] for p in poses])
    t = np.stack([p[1] + [0.0, 0.0, k] for k, p in enumerate(poses)])
    centre = np.random.default_rng(0).normal(scale=0.3, size=(4, 3))
    s = 1.0 / (np.einsum("fij,fj->fi", R, centre) + t)[:, 2]
    R2, t2 = pose_from_weak(s[:, None, None] * R[:, :2], s[:, None] * t[:, :2], None, centre)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    with pytest.raises(CameraError, match="do not match"):
        pose_from_weak(R[:, :2], t[:, :2], None, centre[:2])

def _chain():
    names = ["pelvis", "spine", "head", "l_hip", "l_knee", "r_hip", "r_knee"]
    bones = [("pelvis", "spine"), ("spine", "head"), ("pelvis", "l_hip"), ("l_hip", "l_knee"),
             ("pelvis", "r_hip"), ("r_hip", "r_knee")]
    return KinematicChain(names, bones, name="toy")


def _poses(F):
    rest = np.array([[0, 0, 1.0], [0, 0, 1.3], [0, 0, 1.7], [0, 0.1, 0.95], [0, 0.1, 0.5], [0, -0.1, 0.95],
                     [0, -0.1, 0.5]])
    t = np.arange(F)[:, None, None] / 30
    return rest + 0.05 * np.sin(t * (1 + np.arange(7)[None, :, None]) + np.arange(3)) + [0.01, 0, 0] * t


def _ext(obj):
    """meshcat packs arrays as msgpack extension types; unpack float32 ones."""
    if isinstance(obj, umsgpack.Ext):
        return np.frombuffer(obj.data, dtype=np.float32)
    if isinstance(obj, dict):
        return {k: _ext(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_ext(v) for v in obj]
    return obj


def _commands(html):
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [_ext(umsgpack.unpackb(base64.b64decode(b))) for b in blobs]


def _frustum_points(cmds):
    (obj,) = [c for c in cmds if c["type"] == "set_object" and c["path"].endswith("/camera/frustum")]
    (geometry,) = obj["object"]["geometries"]
    return np.asarray(geometry["data"]["attributes"]["position"]["array"], dtype=float).reshape(-1, 3)


def test_html_draws_the_frustum_where_the_geometry_says(tmp_path):
    chain, poses = _chain(), _poses(20)
    R, t = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]), np.array([0.0, 1.0, 4.0])  # looking along +x
    html = write_html(tmp_path / "v.html", poses, chain=chain, camera=CAMERA, camera_pose=(R, t)).read_text()
    cmds = _commands(html)
    assert "/meshcat/chainspace/camera/frustum" in [c["path"] for c in cmds if c["type"] == "set_object"]
    seg = _frustum_points(cmds)
    assert seg.shape == (16, 3)  # 8 segments: apex to each corner, and the rim
    # this toy chain has no rest pose and no cameras: not turned, only re-centred per frame
    shown = _stand(poses, chain.joint_index(chain.root))
    expected = frustum_corners(CAMERA, (R, t), 0.3 * _extent(shown))
    apex, rim = expected[0], expected[1:]
    np.testing.assert_allclose(seg[0::2][:4], np.tile(apex, (4, 1)), atol=1e-5)
    np.testing.assert_allclose(seg[1::2][:4], rim, atol=1e-5)
    # the camera node follows the skeleton's per-frame re-centring
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    clips = {a["path"]: a["clip"] for a in anim["animations"]}
    keys = clips["/meshcat/chainspace/camera"]["tracks"][0]["keys"]
    np.testing.assert_allclose([k["value"] for k in keys], (shown - poses)[:, 0], atol=1e-5)


def test_html_without_a_pose_uses_the_fitted_weak_camera(tmp_path):
    chain, poses = _chain(), _poses(10)
    R, t = _pose(5)
    centre = poses[0].mean(axis=0)
    s = CAMERA.fx / (R @ centre + t)[2]
    rec = SimpleNamespace(poses=poses, chain=chain, cameras=np.tile(s * R[:2], (10, 1, 1)),
                          translations=np.tile(s * t[:2] + [CAMERA.cx, CAMERA.cy], (10, 1)))
    CAM = PinholeCamera(CAMERA.fx, CAMERA.fx, CAMERA.cx, CAMERA.cy, width=640, height=480)
    cmds = _commands(write_html(tmp_path / "v.html", rec, camera=CAM).read_text())
    seg = _frustum_points(cmds)
    from chainspace.view.viewer import _upright

    Rup = _upright(poses, chain, None, rec.cameras)
    np.testing.assert_allclose(seg[0], Rup @ (-R.T @ t), atol=1e-4)
    with pytest.raises(CameraError, match="camera_pose"):
        write_html(tmp_path / "w.html", poses, chain=chain, camera=CAM)


def test_robot_view_draws_the_frustum_in_the_base_frame(tmp_path):
    pytest.importorskip("pinocchio")
    descriptions = importlib.import_module("chainspace.io.descriptions")
    fit_mod = importlib.import_module("chainspace.robot.fit")
    chain = descriptions.shipped("milling_arm")
    robot = fit_mod.RobotKinematics(chain.metadata["urdf_path"], chain)
    F = 5
    q = robot.clip(robot.q_rest + 0.3 * np.sin(np.arange(F)[:, None] / 3 + np.arange(robot.nq)))
    X = robot.positions(q)
    fit = SimpleNamespace(urdf_path=chain.metadata["urdf_path"], q=q, positions=X, chain=chain,
                          rotation=np.eye(3), translation=np.zeros(3), scale=1.0)
    R, t = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]), np.array([0.0, 1.0, 5.0])  # 5 m along the base's x
    html = write_html(tmp_path / "robot.html", fit=fit, camera=CAMERA, camera_pose=(R, t)).read_text()
    seg = _frustum_points(_commands(html))
    size = float(np.ptp(X, axis=1).max())
    expected = frustum_corners(CAMERA, (R, t), 0.3 * size)
    np.testing.assert_allclose(seg[0], expected[0], atol=1e-5)
    np.testing.assert_allclose(seg[1:8:2], expected[1:], atol=1e-5)
