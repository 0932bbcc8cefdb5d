"""The result drawn over its footage (chainspace.video.overlay, ``chainspace overlay``).

A few frames of the milling arm are filmed (its true projection drawn as filled grey links on a plain
background), fitted, and the overlay drawn over that video: the reprojected chain (green) must land on
the drawn robot. Small images, 6 frames: each test takes a second or two.
"""

import dataclasses
import os

import numpy as np
import pytest
from typer.testing import CliRunner

import chainspace
from chainspace.cli import app
from chainspace.errors import OutputExistsError, TrackError, VideoError
from chainspace.io.results import save_results
from chainspace.robot.fit import fit_joint_angles
from chainspace.synthetic.robot import synthesize
from chainspace.video.overlay import _rms_px, _scene, draw_overlay

cv2 = pytest.importorskip("cv2")

F = 6
WEAK_SIZE = (160, 220)  # (width, height) px: the weak trial's robot spans x 18-90, y 18-198
PIN_SIZE = (320, 240)
BACKGROUND = 90


@pytest.fixture(scope="module")
def arm():
    return chainspace.shipped("milling_arm")


def _film(path, arm, points, size):
    """A video of the robot: every link a thick grey line, every point a filled disc (BGR)."""
    w, h = size
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (w, h))
    seg = [(arm.joint_index(a), arm.joint_index(b)) for a, b in arm.links]
    for uv in points:
        img = np.full((h, w, 3), BACKGROUND, np.uint8)
        for i, j in seg:
            cv2.line(img, tuple(np.round(uv[i]).astype(int)), tuple(np.round(uv[j]).astype(int)), (210, 210, 210), 7)
        for p in np.round(uv).astype(int):
            cv2.circle(img, tuple(p), 5, (210, 210, 210), -1)
        vw.write(img)
    vw.release()
    return path


def _frames(path):
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            return np.array(out)
        out.append(img)


def _green(img):
    """Pixels the overlay drew the chain in (BGR (80, 220, 60), blurred by the codec)."""
    b, g, r = (img[..., k].astype(int) for k in range(3))
    return (g > 150) & (g - r > 60) & (g - b > 60)


def _on_robot(overlay_img, video_img):
    """Fraction of the overlay's chain pixels that fall on the filmed robot (within 2 px)."""
    robot = (np.abs(video_img.astype(int) - BACKGROUND).max(-1) > 40).astype(np.uint8)
    near = cv2.dilate(robot, np.ones((5, 5), np.uint8)).astype(bool)
    green = _green(overlay_img)
    return (green & near).sum() / max(green.sum(), 1), int(green.sum())


@pytest.fixture(scope="module")
def weak(arm, tmp_path_factory):
    """A weak-perspective fit to noisy tracks (0.5 px), and a video of the true projection."""
    tr = synthesize(arm, n_frames=F, noise_px=0.5, seed=0, image_height_px=180, camera="static")
    fit = fit_joint_angles(tr.positions, chain=arm, tracks=tr.tracks, transform="none", accel_std=None)
    truth = chainspace.project(tr.positions, tr.cameras, tr.translations)
    video = _film(tmp_path_factory.mktemp("weak") / "robot.mp4", arm, truth, WEAK_SIZE)
    return tr, fit, video


def test_fit_overlay_puts_the_robot_on_the_robot(weak, tmp_path):
    tr, fit, video = weak
    out = draw_overlay(video, fit, out=tmp_path / "overlay.mp4", progress=False)
    frames, src = _frames(out), _frames(video)
    assert frames.shape == (F, WEAK_SIZE[1], WEAK_SIZE[0], 3)
    for f in (0, F - 1):
        share, n = _on_robot(frames[f], src[f])
        assert n > 200 and share > 0.97, (f, share, n)
    # the same fit with its camera 12 px off: the check fails (it can)
    moved = dataclasses.replace(fit, translations_2d=fit.translations_2d + [12.0, 0.0])
    off = _frames(draw_overlay(video, moved, out=tmp_path / "moved.mp4", progress=False))
    assert _on_robot(off[0], src[0])[0] < 0.6
    assert sorted(os.listdir(tmp_path)) == ["moved.mp4", "overlay.mp4"]  # no temporary file left


def test_rms_written_is_the_fit_reprojection_error(weak):
    _, fit, _ = weak
    rms = _rms_px(_scene(fit))
    assert np.all(rms > 0.15) and np.allclose(rms, fit.residual_px, rtol=1e-6, atol=1e-9)


def test_pinhole_overlay_and_side_panel(arm, weak, tmp_path):
    """A perspective result (a distorting lens) goes through its pinhole camera; the side panel doubles the width."""
    tp = synthesize(arm, n_frames=F, noise_px=0.0, seed=5, camera="pinhole", focal_px=300.0, image_size=PIN_SIZE,
                    distance_reaches=2.0, dist=(-0.15, 0.02, 0.0, 0.0, 0.0))
    # the fit's fields with the true motion and camera: the perspective fit itself is too slow for this suite
    fit = dataclasses.replace(weak[1], q=tp.q, positions_base=None, tracks=tp.tracks, confidence=tp.confidence,
                              intrinsics=tp.intrinsics, camera_pose=(tp.camera_R, tp.camera_t))
    video = _film(tmp_path / "robot.mp4", arm, tp.tracks, PIN_SIZE)
    out = draw_overlay(video, fit, out=tmp_path / "overlay.mp4", side_by_side=True, progress=False)
    frames, src = _frames(out), _frames(video)
    assert frames.shape == (F, PIN_SIZE[1], 2 * PIN_SIZE[0], 3)
    share, n = _on_robot(frames[2, :, :PIN_SIZE[0]], src[2])
    assert n > 200 and share > 0.97, (share, n)
    assert _green(frames[2, :, PIN_SIZE[0]:]).sum() > 100  # the 3D panel shows the chain
    assert np.abs(_rms_px(_scene(fit))).max() < 1e-6  # the truth reprojects onto its own tracks


def test_reconstruction_overlay(arm, weak, tmp_path):
    tr, _, video = weak
    rec = chainspace.reconstruct(tr.tracks, arm)
    out = draw_overlay(video, rec, out=tmp_path / "rec.mp4", progress=False)
    frames, src = _frames(out), _frames(video)
    assert len(frames) == F
    share, n = _on_robot(frames[1], src[1])
    assert n > 200 and share > 0.95, (share, n)
    rms = _rms_px(_scene(rec))
    assert np.sqrt(np.mean(rms ** 2)) == pytest.approx(rec.reprojection_error(), rel=1e-6)


def test_frame_count_mismatch_and_unreadable_video(weak, tmp_path):
    tr, fit, video = weak
    folder = tmp_path / "frames"
    folder.mkdir()
    for f, img in enumerate(_frames(video)[:F - 1]):
        cv2.imwrite(str(folder / f"f{f}.png"), img)
    with pytest.raises(TrackError, match=rf"has {F - 1} frames but the result has {F}"):
        draw_overlay(folder, fit, out=tmp_path / "a.mp4", progress=False)
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\x00not a video" * 50)
    with pytest.raises(VideoError, match="broken.mp4: not a video OpenCV can read"):
        draw_overlay(broken, fit, out=tmp_path / "b.mp4", progress=False)
    with pytest.raises(VideoError, match="no such video"):
        draw_overlay(tmp_path / "missing.mp4", fit, out=tmp_path / "c.mp4", progress=False)
    with pytest.raises(TrackError, match=r"tracks have shape \(5, 9, 2\), expected \(6, 9, 2\)"):
        draw_overlay(video, fit, tracks=tr.tracks[:5], out=tmp_path / "d.mp4", progress=False)
    with pytest.raises(TrackError, match="fps must be a finite number > 0"):
        draw_overlay(folder, fit, out=tmp_path / "f.mp4", fps=0.0, progress=False)
    with pytest.raises(TrackError, match="needs a JointFit or a Reconstruction"):
        draw_overlay(video, tr.tracks, out=tmp_path / "e.mp4", progress=False)
    assert sorted(os.listdir(tmp_path)) == ["broken.mp4", "frames"]  # nothing written


def test_tracks_from_a_file(weak, tmp_path):
    """tracks=FILE: those tracks are drawn, not the fit's own."""
    from chainspace.io.tracks import save_tracks

    tr, fit, video = weak
    save_tracks(tmp_path / "t.csv", tr.tracks + [3.0, 4.0], fit.chain.joints)
    own = _frames(draw_overlay(video, fit, out=tmp_path / "own.mp4", progress=False))[0]
    moved = _frames(draw_overlay(video, fit, tracks=tmp_path / "t.csv", out=tmp_path / "moved.mp4",
                                 progress=False))[0]

    def orange_at(img, points):  # share of points where a cross is drawn (the crosses' centres)
        u, v = np.round(points).astype(int).T
        b, g, r = (img[v, u, k].astype(int) for k in range(3))
        return np.mean((r > 180) & (b < 120) & (r - b > 100))

    at = tr.tracks[0] + [3.0, 4.0]  # 5 px off the fitted tracks, off the + of their crosses
    assert orange_at(moved, at) > 0.8 and orange_at(own, at) < 0.2


def test_image_folder_in_numeric_order(weak, tmp_path):
    _, fit, video = weak
    folder = tmp_path / "frames"
    folder.mkdir()
    src = _frames(video)
    for f in range(F):  # names that sort wrongly as text (f16 before f8)
        cv2.imwrite(str(folder / f"f{f * 8}.png"), src[f])
    out = _frames(draw_overlay(folder, fit, out=tmp_path / "o.mp4", fps=12.0, progress=False))
    assert len(out) == F
    for f in (1, F - 1):  # frame f of the result is drawn on frame f of the folder
        assert _on_robot(out[f], src[f])[0] > 0.97
    # an output without a suffix is a folder of PNGs: lossless, the footage away from the drawing is unchanged
    pngs = sorted(draw_overlay(folder, fit, out=tmp_path / "o", progress=False).glob("frame_*.png"))
    last = cv2.imread(str(pngs[-1]))
    assert len(pngs) == F and _on_robot(last, src[F - 1])[0] > 0.97
    assert np.mean((last == src[F - 1]).all(-1)) > 0.5


def test_existing_output_is_kept(weak, tmp_path):
    _, fit, video = weak
    out = tmp_path / "overlay.mp4"
    out.write_text("mine")
    with pytest.raises(OutputExistsError, match="overwrite=True"):
        draw_overlay(video, fit, out=out, progress=False)
    assert out.read_text() == "mine"
    draw_overlay(video, fit, out=out, overwrite=True, progress=False)
    assert len(_frames(out)) == F


def test_cli_overlay(weak, tmp_path):
    _, fit, video = weak
    saved = [p for p in save_results(fit, tmp_path / "fit") if p.suffix == ".npz"][0]
    out = tmp_path / "overlay.mp4"
    runner = CliRunner()
    res = runner.invoke(app, ["overlay", str(video), str(saved), "--out", str(out), "--side-by-side"])
    assert res.exit_code == 0, res.output
    assert f"{F}/{F}" in res.output and "\r" not in res.output  # the progress bar as plain lines (no terminal)
    frames = _frames(out)
    assert frames.shape == (F, WEAK_SIZE[1], 2 * WEAK_SIZE[0], 3)
    assert _on_robot(frames[0, :, :WEAK_SIZE[0]], _frames(video)[0])[0] > 0.97  # the saved fit reloads whole
    again = runner.invoke(app, ["overlay", str(video), str(saved), "--out", str(out)])
    assert again.exit_code == 2 and "use --overwrite" in again.output


def test_cli_overlay_help_has_an_example():
    res = CliRunner().invoke(app, ["overlay", "--help"])
    assert res.exit_code == 0 and "Example: chainspace overlay" in res.output


def test_side_view_is_level_and_a_quarter_turn_from_the_camera():
    from chainspace.cameras.weak import rodrigues
    from chainspace.video.overlay import _side_view

    R0 = rodrigues(np.array([0.3, -0.5, 0.2]))  # a tilted camera: rows right, down, forward
    for up in ([0.0, 0.0, 1.0], None):
        V = _side_view(R0, up)
        u = -R0[1] if up is None else np.array(up)
        assert np.allclose(V @ V.T, np.eye(3)) and np.isclose(np.linalg.det(V), 1.0)
        assert np.allclose(V[1], -u)  # level: the panel's down is the vertical
        assert abs(V[2] @ R0[2]) < 1e-9  # looking across the camera's view direction
