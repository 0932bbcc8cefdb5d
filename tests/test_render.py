"""The renderer puts the robot where Pinocchio's forward kinematics and the camera say, with and without
lens distortion; it writes a video and its truth, reproducibly, and never over a user's file."""

import cv2
import numpy as np
import pytest

pytest.importorskip("pybullet")

from chainspace.errors import OutputExistsError  # noqa: E402
from chainspace.video.render import RobotRenderer, load_truth, render_trial  # noqa: E402


@pytest.fixture(scope="module")
def trial(milling_arm_urdf):
    from chainspace.synthetic.robot import synthesize

    return synthesize(milling_arm_urdf, n_frames=3, camera="pinhole", image_size=(320, 240), noise_px=0.0,
                      seed=2, trajectory="milling", distance_reaches=1.5)


@pytest.mark.parametrize("dist", [None, (-0.25, 0.08, 0.002, -0.001, 0.0)], ids=["pinhole", "distorted"])
def test_rendered_robot_covers_its_projected_points(trial, dist):
    """Each link origin of the arm (inside its boxes and cylinders) projects onto a pixel of the robot,
    and the robot's silhouette lies round those points, not elsewhere in the image."""
    from chainspace.cameras.pinhole import PinholeCamera

    c = trial.intrinsics
    cam = PinholeCamera(c.fx, c.fy, c.cx, c.cy, dist, 320, 240)
    with RobotRenderer(trial.chain, cam, trial.camera_R, trial.camera_t, seed=0, shadow=False) as r:
        img, seg = r.render(trial.q[1])
        pts = r.truth(trial.q[1:2])["points"][0]
        body = r.body
    robot = seg == body
    inside = [j for j, n in enumerate(trial.chain.joints) if n != "tool_tip"]  # the tip is the tool's end face
    u, v = np.rint(pts[inside]).astype(int).T
    ok = (u >= 0) & (u < 320) & (v >= 0) & (v < 240)
    assert ok.sum() >= 5
    # within a pixel of the silhouette: some origins sit on a link's end face, where rasterising (and the
    # distortion's remap) decides the last pixel either way
    near = cv2.dilate(robot.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert near[v[ok], u[ok]].all(), "a link origin projects off the rendered robot"
    ys, xs = np.nonzero(robot)
    lo, hi = pts[inside][ok].min(0), pts[inside][ok].max(0)
    # the silhouette extends past the points by at most the links' thickness (about 0.5 m: < 1/3 of its span)
    span = (hi - lo).max()
    assert xs.min() > lo[0] - span / 3 and xs.max() < hi[0] + span / 3
    assert ys.min() > lo[1] - span / 3 and ys.max() < hi[1] + span / 3
    assert img.shape == (240, 320, 3) and img[robot].std() > 10  # textured, not flat


def test_render_video_writes_truth_reproducibly_and_refuses_to_overwrite(trial, tmp_path):
    cv2 = pytest.importorskip("cv2")
    res = render_trial(trial, tmp_path / "clip", seed=3, supersample=1)  # a folder of PNGs
    frames = sorted((tmp_path / "clip").glob("frame_*.png"))
    assert len(frames) == 3 and res.image_size == (320, 240) and res.truth.name == "clip.truth.npz"
    truth = load_truth(tmp_path / "clip")
    assert truth["points"].shape == (3, trial.chain.n_joints, 2)
    assert np.allclose(truth["q"], trial.q) and np.allclose(truth["R"], trial.camera_R)
    with pytest.raises(OutputExistsError):
        render_trial(trial, tmp_path / "clip", seed=3, supersample=1)
    again = render_trial(trial, tmp_path / "again", seed=3, supersample=1)
    a = cv2.imread(str(frames[0]))
    b = cv2.imread(str(sorted(again.video.glob("frame_*.png"))[0]))
    assert np.array_equal(a, b), "the same seed renders the same frame"
