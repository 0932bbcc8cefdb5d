"""frame_writer: MP4 or image folder, atomic, never replacing what exists unless asked."""

import numpy as np
import pytest

from chainspace.errors import OutputExistsError, VideoError
from chainspace.video.reader import open_video
from chainspace.video.writer import frame_writer

pytest.importorskip("cv2")

W, H, F = 64, 48, 5


def _frames(n=F, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (n, H, W, 3), dtype=np.uint8)


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_image_folder_round_trips_exactly(tmp_path):
    src = _frames()
    with frame_writer(tmp_path / "clip", 12.0, (W, H)) as w:
        for img in src:
            w.write(img)
        assert not (tmp_path / "clip").exists(), "the target appears only once every frame is written"
    back = np.stack(list(open_video(tmp_path / "clip", fps=12.0)))
    assert np.array_equal(back, src) and not _leftovers(tmp_path)


def test_mp4_has_the_frames_size_and_rate(tmp_path):
    src = _frames()
    with frame_writer(tmp_path / "clip.mp4", 12.0, (W, H)) as w:
        for img in src:
            w.write(img)
    video = open_video(tmp_path / "clip.mp4")
    assert (video.frame_count, video.size, video.fps) == (F, (W, H), 12.0)
    assert not _leftovers(tmp_path)


@pytest.mark.parametrize("name", ["clip.mp4", "clip"])
def test_failed_write_leaves_nothing(tmp_path, name):
    with pytest.raises(RuntimeError, match="stop"), frame_writer(tmp_path / name, 12.0, (W, H)) as w:
        w.write(_frames(1)[0])
        raise RuntimeError("stop")
    assert not list(tmp_path.iterdir()), "neither the target nor a temporary file or folder is left"


@pytest.mark.parametrize("name", ["clip.mp4", "clip"])
def test_existing_target_kept_unless_overwrite(tmp_path, name):
    target = tmp_path / name
    if target.suffix:
        target.write_text("mine")
    else:
        target.mkdir()
        (target / "mine.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="overwrite=True"), frame_writer(target, 12.0, (W, H)):
        pass
    assert (target.read_text() if target.suffix else (target / "mine.txt").read_text()) == "mine"
    with frame_writer(target, 12.0, (W, H), overwrite=True) as w:
        for img in _frames(2):
            w.write(img)
    assert len(open_video(target, fps=12.0)) == 2 and not (target / "mine.txt").exists()
    assert not _leftovers(tmp_path)


def test_bad_requests_are_clear_errors(tmp_path):
    with pytest.raises(VideoError, match=r"clip\.gif: write a video"):
        frame_writer(tmp_path / "clip.gif", 12.0, (W, H)).__enter__()
    with pytest.raises(VideoError, match="fps must be a finite number > 0"):
        frame_writer(tmp_path / "clip.mp4", float("nan"), (W, H)).__enter__()
    with pytest.raises(VideoError, match=r"clip\.mp4: frame 1 is 32 x 48 px, the video is 64 x 48"), \
            frame_writer(tmp_path / "clip.mp4", 12.0, (W, H)) as w:
        w.write(_frames(1)[0])
        w.write(_frames(1)[0][:, :32])
    assert not list(tmp_path.iterdir())
