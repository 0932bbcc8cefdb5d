"""The standalone HTML viewer: self-contained, small per frame, and animating the right positions."""

from __future__ import annotations

import importlib
import base64
import re
from types import SimpleNamespace

import numpy as np
import pytest

from chainspace.chain import KinematicChain
from chainspace.errors import OutputExistsError, TrackError
from chainspace.view.viewer import write_html

umsgpack = pytest.importorskip("umsgpack")


def _chain() -> KinematicChain:
    names = ["pelvis", "spine", "head", "l_hip", "l_knee", "r_hip", "r_knee"]
    bones = [("pelvis", "spine"), ("spine", "head"), ("pelvis", "l_hip"), ("l_hip", "l_knee"),
             ("pelvis", "r_hip"), ("r_hip", "r_knee")]
    return KinematicChain(names, bones, name="toy")


def _poses(F: int, seed: int = 0) -> np.ndarray:
    rest = np.array([[0, 0, 1.0], [0, 0, 1.3], [0, 0, 1.7], [0, 0.1, 0.95], [0, 0.1, 0.5], [0, -0.1, 0.95],
                     [0, -0.1, 0.5]])
    t = np.arange(F)[:, None, None] / 30
    wobble = 0.05 * np.sin(t * (1 + np.arange(7)[None, :, None]) + np.arange(3))
    return rest + wobble + np.array([0.01, 0.0, 0.0]) * t  # walking slowly along x


def _commands(html: str) -> list[dict]:
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def test_html_is_standalone_and_animates_joint_positions(tmp_path):
    chain, poses = _chain(), _poses(40)
    path = write_html(tmp_path / "v.html", poses, chain=chain, fps=25)
    html = path.read_text()
    assert "MeshCat.Viewer" in html and "<script src" not in html.replace(" ", "")
    remote = [u for u in re.findall(r"https?://[^\s\"')]+", html) if "www.w3.org" not in u]
    assert remote == []  # meshcat's JavaScript is inlined; nothing is fetched from the network
    cmds = _commands(html)
    anim = [c for c in cmds if c["type"] == "set_animation"]
    assert len(anim) == 1
    clips = {a["path"]: a["clip"] for a in anim[0]["animations"]}
    assert all(c["fps"] == 25 for c in clips.values())
    # each joint's position track is the pose, centred on the root in x, y and standing on z = 0
    expected = poses.copy()
    expected[..., :2] -= poses[:, :1, :2]
    expected[..., 2] -= expected[..., 2].min()
    for j, name in enumerate(chain.joints):
        clip = clips[f"/meshcat/chainspace/reconstruction/joints/{name}"]
        (track,) = [t for t in clip["tracks"] if t["name"] == ".position"]
        values = np.array([k["value"] for k in track["keys"]])
        assert [k["time"] for k in track["keys"]] == list(range(40))
        np.testing.assert_allclose(values, expected[:, j], atol=1e-6)
    # bones hang from their parent joint: they turn, and stretch since these poses keep no bone length
    bone = clips["/meshcat/chainspace/reconstruction/joints/l_hip/to_l_knee"]
    assert {t["name"] for t in bone["tracks"]} == {".quaternion", ".scale"}
    # geometry is created once, not per frame
    objects = [c for c in cmds if c["type"] == "set_object"]
    assert len(objects) == chain.n_joints + chain.n_bones


def test_size_grows_by_little_per_frame(tmp_path):
    chain = _chain()
    small = write_html(tmp_path / "s.html", _poses(10), chain=chain).stat().st_size
    big = write_html(tmp_path / "b.html", _poses(1010), chain=chain, truth=_poses(1010, 1)).stat().st_size
    per_frame_and_joint = (big - small) / 1000 / (2 * chain.n_joints)
    # a position, a rotation and a stretch per joint and frame in base64 msgpack: ~100 bytes
    assert per_frame_and_joint < 150, per_frame_and_joint
    assert big < 3e6


def test_bad_input_and_overwrite(tmp_path):
    chain, poses = _chain(), _poses(5)
    write_html(tmp_path / "v.html", poses, chain=chain)
    with pytest.raises(OutputExistsError):
        write_html(tmp_path / "v.html", poses, chain=chain)
    write_html(tmp_path / "v.html", poses, chain=chain, overwrite=True)
    bad = poses.copy()
    bad[3, 2] = np.nan
    with pytest.raises(TrackError, match="joint 2 in frame 3"):
        write_html(tmp_path / "w.html", bad, chain=chain)
    with pytest.raises(TrackError, match="shape"):
        write_html(tmp_path / "w.html", poses[:, :3], chain=chain)
    with pytest.raises(TrackError, match="chain="):
        write_html(tmp_path / "w.html", poses)
    assert not (tmp_path / "w.html").exists()


def test_reconstruction_is_turned_upright(tmp_path):
    """A reconstruction in a camera frame (here the truth turned on its side) is shown Z-up."""
    chain = _chain().with_rest_pose(_poses(1)[0])
    truth = _poses(20)
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    rec = SimpleNamespace(poses=truth @ R.T, chain=chain, cameras=None)
    cmds = _commands(write_html(tmp_path / "v.html", rec).read_text())
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    clips = {a["path"]: a["clip"] for a in anim["animations"]}
    head = clips["/meshcat/chainspace/reconstruction/joints/head"]["tracks"][0]["keys"]
    pelvis = clips["/meshcat/chainspace/reconstruction/joints/pelvis"]["tracks"][0]["keys"]
    assert all(h["value"][2] - p["value"][2] > 0.6 for h, p in zip(head, pelvis, strict=True))


def test_robot_fit_drives_the_urdf_geometry(tmp_path):
    pytest.importorskip("pinocchio")
    descriptions = importlib.import_module("chainspace.io.descriptions")
    fit_mod = importlib.import_module("chainspace.robot.fit")
    chain = descriptions.shipped("milling_arm")
    robot = fit_mod.RobotKinematics(chain.metadata["urdf_path"], chain)
    F = 30
    q = robot.clip(robot.q_rest + 0.4 * np.sin(np.arange(F)[:, None] / 10 + np.arange(robot.nq)))
    X = robot.positions(q)
    # the fit's points live in the reconstruction's frame: x_rec = s R x_base + t
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
    s, t = 2.5, np.array([0.1, -0.2, 3.0])
    fit = SimpleNamespace(urdf_path=chain.metadata["urdf_path"], q=q, positions=s * X @ R.T + t, chain=chain,
                          rotation=R, translation=t, scale=s)
    html = write_html(tmp_path / "robot.html", fit=fit, truth=X).read_text()
    cmds = _commands(html)
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    paths = [a["path"] for a in anim["animations"]]
    parts = [p for p in paths if "/robot/visuals/" in p]
    assert len(parts) >= 6 and any("/truth/" in p for p in paths)
    # the tool tip point drawn over the robot (mapped back to the base frame) is where the angles put it
    tip = {a["path"]: a["clip"] for a in anim["animations"]}[
        f"/meshcat/chainspace/reconstruction/joints/{chain.joints[-1]}"]["tracks"][0]["keys"]
    np.testing.assert_allclose([k["value"] for k in tip], X[:, -1], atol=1e-5)


def test_live_viewer_serves_the_scene():
    import urllib.request

    from chainspace.view.viewer import show

    vis = show(_poses(10), chain=_chain())
    try:
        url = vis.url()
        assert url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200 and b"meshcat" in page.read().lower()
        # the server holds the same scene the standalone file gets: geometry plus one animation
        cmds = _commands(vis.static_html())
        assert sum(c["type"] == "set_animation" for c in cmds) == 1
        assert sum(c["type"] == "set_object" for c in cmds) == _chain().n_joints + _chain().n_bones
    finally:
        vis.window.server_proc.kill()
        vis.window.server_proc.wait(timeout=10)
