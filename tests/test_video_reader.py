"""Reading frames: video files through OpenCV, folders of numbered images, and clear errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from chainspace import VideoError, open_video
from chainspace.video.reader import natural_key


def _frame(k: int, size=(64, 48)) -> np.ndarray:
    """A frame whose pixels say its number (k in every pixel of the blue channel)."""
    img = np.zeros((size[1], size[0], 3), np.uint8)
    img[..., 0] = 10 * k
    return img


def _folder(path, names, size=(64, 48)):
    path.mkdir()
    for k, name in enumerate(names):
        cv2.imwrite(str(path / name), _frame(k, size))
    return path


def test_folder_frames_come_in_natural_order(tmp_path):
    names = [f"f{k}.png" for k in range(12)]  # f10 and f11 sort before f2 as text
    d = _folder(tmp_path / "frames", names)
    with open_video(d, fps=25) as video:
        assert (video.fps, video.size, video.frame_count) == (25.0, (64, 48), 12)
        seen = [int(img[0, 0, 0]) // 10 for img in video]
        assert seen == list(range(12))
        assert [int(img[0, 0, 0]) // 10 for img in video.frames(9, 11)] == [9, 10]
        assert video.frame(10)[0, 0, 0] == 100


def test_natural_key_mixes_padding():
    names = ["f10.png", "f009.png", "f2.png", "f0011.jpg"]
    assert sorted(names, key=natural_key) == ["f2.png", "f009.png", "f10.png", "f0011.jpg"]


@pytest.mark.parametrize("fps", [None, 0, -5, float("nan"), float("inf")])
def test_folder_needs_a_positive_finite_fps(tmp_path, fps):
    d = _folder(tmp_path / "frames", ["a1.png", "a2.png"])
    with pytest.raises(VideoError, match="fps"):
        open_video(d, fps=fps)


def test_empty_folder_and_missing_path_are_clear(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(VideoError, match="empty: the folder holds no images"):
        open_video(tmp_path / "empty", fps=30)
    with pytest.raises(VideoError, match="nowhere.mp4: no such video"):
        open_video(tmp_path / "nowhere.mp4")


def test_mixed_image_sizes_name_the_file_and_frame(tmp_path):
    d = _folder(tmp_path / "frames", ["f1.png", "f2.png"])
    cv2.imwrite(str(d / "f3.png"), _frame(3, (32, 48)))
    video = open_video(d, fps=10)
    with pytest.raises(VideoError, match=r"f3\.png: frame 2 is 32x48 px .* 64x48"):
        list(video)


def test_unreadable_image_in_a_folder(tmp_path):
    d = _folder(tmp_path / "frames", ["f1.png"])
    (d / "f2.png").write_bytes(b"not a png")
    with pytest.raises(VideoError, match=r"f2\.png: frame 1 .* not a readable image"):
        list(open_video(d, fps=10))


def test_video_file_is_streamed_with_its_rate_and_size(tmp_path):
    path = tmp_path / "clip.avi"  # MJPG: near-lossless enough to read each frame's number back
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 12.0, (64, 48))
    assert writer.isOpened()
    for k in range(8):
        writer.write(_frame(k))
    writer.release()
    with open_video(path) as video:
        assert (video.fps, video.size, video.frame_count) == (12.0, (64, 48), 8)
        assert [round(img[..., 0].mean() / 10) for img in video.frames(3)] == [3, 4, 5, 6, 7]
    assert open_video(path, fps=50).fps == 50.0


def test_corrupt_and_empty_video_files_are_clear(tmp_path, rng):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(VideoError, match="junk.mp4: .*(not a video|no readable frame)"):
        open_video(junk)
    empty = tmp_path / "empty.mov"
    empty.write_bytes(b"")
    with pytest.raises(VideoError, match="empty.mov: the file is empty"):
        open_video(empty)
