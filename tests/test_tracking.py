"""Tracking points through video: sub-pixel accuracy, loss, re-anchoring, key frames, the CLI, and the
road from a video's tracks into reconstruct."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from chainspace import VideoError, load_tracks, track_points, track_video
from chainspace.cli import app
from chainspace.video.keyframes import load_keyframes

W, H = 160, 120


def _texture(rng, shape, sigma=2.0):
    """Smoothed random noise at full contrast: the surface LK needs."""
    noise = cv2.GaussianBlur(rng.uniform(0, 255, shape).astype(np.float32), (0, 0), sigma)
    return 128 + 60 * (noise - noise.mean()) / noise.std()


def _moving_scene(path, rng, shifts):
    """A PNG folder whose frame k shows a large texture moved by ``shifts[k]`` (x, y) px."""
    tex = _texture(rng, (2 * H, 2 * W))
    path.mkdir()
    for k, (dx, dy) in enumerate(shifts):
        # dst(x) = tex(x + W/2 - dx): the content moves by +dx
        M = np.float32([[1, 0, -W / 2 + dx], [0, 1, -H / 2 + dy]])
        img = cv2.warpAffine(tex, M, (W, H), flags=cv2.INTER_CUBIC)
        cv2.imwrite(str(path / f"frame{k}.png"), np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return path


def test_a_subpixel_shift_is_recovered_to_a_tenth_of_a_pixel(tmp_path, rng):
    step = np.array([0.37, -0.21])
    shifts = np.arange(4)[:, None] * step
    d = _moving_scene(tmp_path / "v", rng, shifts)
    start = np.array([[50.0, 60.0], [100.0, 40.0], [80.3, 70.6]])
    kf = {"0": {f"p{j}": start[j].tolist() for j in range(3)}}
    result = track_points(d, kf, fps=30)
    assert result.tracks.shape == (4, 3, 2) and result.names == ["p0", "p1", "p2"]
    moved = result.tracks - result.tracks[:1]
    np.testing.assert_allclose(moved, np.broadcast_to(shifts[:, None], moved.shape), atol=0.1)
    assert (result.confidence > 0.5).all() and result.image_size == (W, H) and result.fps == 30


def test_a_point_leaving_the_image_becomes_nan_with_confidence_zero(tmp_path, rng):
    shifts = np.arange(8)[:, None] * [6.0, 0.0]  # 6 px to the right per frame
    d = _moving_scene(tmp_path / "v", rng, shifts)
    kf = {"0": {"edge": [140.0, 60.0], "middle": [40.0, 60.0]}}
    result = track_points(d, kf, fps=30, window=11)
    x_edge = 140 + shifts[:, 0]
    inside = x_edge <= W - 1
    assert not inside.all()
    lost = np.isnan(result.tracks[:, 0, 0])
    assert lost[~inside].all() and (result.confidence[lost, 0] == 0).all()
    np.testing.assert_allclose(result.tracks[inside & ~lost, 0, 0], x_edge[inside & ~lost], atol=0.1)
    # once lost, a point stays lost without a key frame; the other point carries on
    assert lost[np.argmax(lost):].all()
    np.testing.assert_allclose(result.tracks[:, 1, 0], 40 + shifts[:, 0], atol=0.15)
    assert 0 < result.lost_fraction < 0.5


def test_a_later_key_frame_re_anchors_and_reports_the_drift(tmp_path, rng):
    shifts = np.arange(6)[:, None] * [6.0, 1.0]
    d = _moving_scene(tmp_path / "v", rng, shifts)
    # frame 3: "a" is placed 2 px right of where it is (a user's imprecise click), "b" (lost past
    # the edge) comes back, and "c" is given up as hidden
    kf = {"0": {"a": [40.0, 50.0], "b": [150.0, 60.0], "c": [60.0, 30.0]},
          "3": {"a": [40.0 + 18 + 2, 53.0], "b": [100.0, 80.0], "c": None, "d": [30.0, 90.0]}}
    result = track_points(d, kf, fps=30, window=11)
    a, b, c = result.tracks[:, 0], result.tracks[:, 1], result.tracks[:, 2]
    assert result.drift[3]["a"] == pytest.approx(2.0, abs=0.1)
    assert np.isnan(result.drift[3]["b"])  # lost before the re-anchor: no drift to measure
    assert "c" not in result.drift[3] and "d" not in result.drift[3]  # hidden; placed for the first time
    assert np.isnan(result.tracks[:3, 3]).all() and np.isfinite(result.tracks[3:, 3]).all()
    np.testing.assert_allclose(a[3], [60.0, 53.0], atol=1e-4)  # the key frame wins
    np.testing.assert_allclose(a[4:] - a[3], shifts[4:] - shifts[3], atol=0.1)  # tracked on from there
    assert np.isnan(b[2, 0]) and np.isfinite(b[3:]).all()
    np.testing.assert_allclose(b[3:] - [100.0, 80.0], shifts[3:] - shifts[3], atol=0.1)
    assert np.isnan(c[3:]).all() and (result.confidence[3:, 2] == 0).all()
    assert result.confidence[3, 0] == 1.0 and result.max_drift_px == pytest.approx(2.0, abs=0.1)


@pytest.mark.parametrize(("keyframes", "message"), [
    ({"x": {"a": [1, 2]}}, "'x' is not a frame index"),
    ({"-1": {"a": [1, 2]}}, "not a frame index"),
    ({"9": {"a": [1, 2]}}, "key frame 9 is past the video's end"),
    ({"0": {"a": [1, float("nan")]}}, "point 'a': .* not finite"),
    ({"0": {"a": [1, 2, 3]}}, r"point 'a': expected \[x, y\]"),
    ({"0": {"a": [W + 3, 2]}}, "outside the 160x120 px image"),
    ({"0": {}}, "at least one point"),
    ({}, "at least one frame"),
    ({"0": {"a": None}}, "place no point"),
])
def test_bad_key_frames_are_clear(keyframes, message):
    with pytest.raises(VideoError, match=message):
        load_keyframes(keyframes, image_size=(W, H), frame_count=5)


def test_key_frame_names_are_checked_against_the_chain(tmp_path):
    path = tmp_path / "kf.json"
    path.write_text(json.dumps({"0": {"link_2": [10, 20], "elbow": [30, 40]}}))
    with pytest.raises(VideoError, match=r"kf.json: key frame 0: 'elbow' is not a point of the chain"):
        load_keyframes(path, names=["base_link", "link_2"])
    path.write_text('{"0": {"a": [1, 2],}}')
    with pytest.raises(VideoError, match=r"kf.json:1: not valid JSON"):
        load_keyframes(path)


@pytest.fixture
def clip(tmp_path, rng):
    """A tiny MP4 of a moving texture, and key frames for it."""
    tex = _texture(rng, (2 * H, 2 * W), sigma=3.0).astype(np.uint8)
    path = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 24.0, (W, H))
    assert writer.isOpened()
    for k in range(12):
        writer.write(cv2.cvtColor(np.ascontiguousarray(tex[40 + k:40 + k + H, 50 + 2 * k:50 + 2 * k + W]),
                                  cv2.COLOR_GRAY2BGR))
    writer.release()
    kf = tmp_path / "kf.json"
    kf.write_text(json.dumps({"0": {"a": [60, 50], "b": [100, 70]}, "8": {"a": [60 - 16, 50 - 8]}}))
    return path, kf


def test_track_video_writes_what_load_tracks_reads(clip, tmp_path):
    video, kf = clip
    out = tmp_path / "tracks.csv"
    result = track_video(video, kf, out, progress=False)
    P, C, names = load_tracks(out)
    assert names == ["a", "b"] and P.shape == (12, 2, 2)
    np.testing.assert_allclose(P, result.tracks, atol=1e-5, equal_nan=True)
    np.testing.assert_allclose(C, result.confidence, atol=1e-9)
    # the texture moves 2 px left and 1 px up per frame; mp4v's compression costs some accuracy
    np.testing.assert_allclose(result.tracks[:, 1] - [100, 70], np.arange(12)[:, None] * [-2, -1], atol=0.5)
    with pytest.raises(Exception, match="already exists"):
        track_video(video, kf, out, progress=False)


def test_cli_track_end_to_end(clip, tmp_path):
    video, kf = clip
    out = tmp_path / "t.csv"
    runner = CliRunner()
    res = runner.invoke(app, ["track", str(video), "--points", str(kf), "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "drift at key frame 8: a " in res.output and "12 frames x 2 points" in res.output
    assert load_tracks(out)[0].shape == (12, 2, 2)
    again = runner.invoke(app, ["track", str(video), "--points", str(kf), "--out", str(out)])
    assert again.exit_code == 2 and "already exists; use --overwrite" in again.output
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 2000, dtype=np.uint8).tobytes())
    bad = runner.invoke(app, ["track", str(junk), "--points", str(kf), "--out", str(tmp_path / "u.csv")])
    assert bad.exit_code == 2 and "junk.mp4" in bad.output
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "f1.png"), np.zeros((H, W, 3), np.uint8))
    nofps = runner.invoke(app, ["track", str(folder), "--points", str(kf), "--out", str(tmp_path / "v.csv")])
    assert nofps.exit_code == 2 and "--fps" in nofps.output


def _blob_video(path, tracks, size, rng, radius=6):
    """PNG frames with one textured disc per point at its (sub-pixel) track position."""
    w, h = size
    side = 2 * radius + 1
    yy, xx = np.mgrid[:side, :side] - radius
    mask = ((xx ** 2 + yy ** 2) <= radius ** 2).astype(np.float32)
    patches = [_texture(rng, (side, side), sigma=1.0) for _ in range(tracks.shape[1])]
    path.mkdir()
    for f, frame_points in enumerate(tracks):
        img = np.full((h, w), 90.0, np.float32)
        for patch, (x, y) in zip(patches, frame_points, strict=True):
            M = np.float32([[1, 0, x - radius], [0, 1, y - radius]])
            a = cv2.warpAffine(mask, M, (w, h), flags=cv2.INTER_LINEAR)
            img = img * (1 - a) + cv2.warpAffine(patch * mask, M, (w, h), flags=cv2.INTER_LINEAR)
        cv2.imwrite(str(path / f"{f}.png"), np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return path


def test_a_videos_tracks_go_straight_into_reconstruct(tmp_path, rng):
    """Part 4 of issue 18: track -> reconstruct with the video's own intrinsics and image size."""
    import chainspace as cs

    chain = cs.shipped("milling_arm")
    trial = cs.synthesize(chain, n_frames=10, noise_px=0.0, seed=0, camera="pinhole", image_size=(480, 360))
    d = _blob_video(tmp_path / "arm", trial.tracks, (480, 360), rng)
    kf = {"0": {n: trial.tracks[0, j].tolist() for j, n in enumerate(chain.joints)}}
    result = track_points(d, kf, chain=chain, fps=trial.fps, window=9)
    assert result.names == list(chain.joints) and result.image_size == (480, 360)
    err = np.linalg.norm(result.tracks - trial.tracks, axis=2)
    assert np.nanmedian(err) < 0.3, np.nanmax(err, axis=0)
    camera = result.camera(trial.intrinsics.K)
    assert camera.image_size == (480, 360)
    rec = cs.reconstruct(result.tracks, chain, confidence=result.confidence, intrinsics=camera)
    assert rec.converged
    # as good as the reconstruction from the true tracks, within 2 cm (link_3 and link_4 nearly coincide
    # in the image, so their discs overlap and their tracks are the worst, about 1 px)
    ref = cs.reconstruct(trial.tracks, chain, intrinsics=trial.intrinsics)
    assert cs.error_3d(rec.poses, trial.positions) < cs.error_3d(ref.poses, trial.positions) + 0.02  # metres


def test_the_documented_key_frame_example_loads():
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "docs" / "formats" / "examples" / "keyframes.json"
    kf = load_keyframes(path, names=["base_link", "link_1", "link_2", "tool_tip"], image_size=(1920, 1080))
    assert list(kf) == [0, 150] and kf[0]["link_2"] == (455.0, 402.25) and kf[150]["tool_tip"] is None


def test_a_rotating_patch_is_followed_without_drift(tmp_path, rng):
    """1.5 degrees per frame about a centre 29 px away: LK's translation steps pick up a bias that
    adds up; aligning the key frame's patch (ECC, rotation and shift) keeps the point on the spot."""
    src = np.clip(_texture(rng, (H, W)), 0, 255).astype(np.float32)
    centre, start = (80.0, 60.0), np.array([105.0, 75.0])
    d = tmp_path / "v"
    d.mkdir()
    truth = []
    for k in range(12):
        M = cv2.getRotationMatrix2D(centre, 1.5 * k, 1.0)  # src -> frame
        img = cv2.warpAffine(src, M, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        cv2.imwrite(str(d / f"{k}.png"), np.clip(np.rint(img), 0, 255).astype(np.uint8))
        truth.append(M @ [*start, 1.0])
    result = track_points(d, {"0": {"p": start.tolist()}}, fps=30)
    err = np.linalg.norm(result.tracks[:, 0] - np.array(truth), axis=1)
    assert err.max() < 0.1, err


def test_the_default_patch_grows_with_the_image_and_stays_odd():
    from chainspace.video.tracking import default_window

    sides = [default_window(h) for h in (240, 480, 720, 1080, 2160)]
    assert sides[:2] == [21, 21] and sides[3] == 31  # 31 px at 1080 rows: no marker lost on the rendered UR10
    assert sides == sorted(sides) and all(s % 2 == 1 for s in sides)
