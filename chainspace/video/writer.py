"""Frames out: an MP4 (OpenCV, ``mp4v``) or a folder of numbered images, written atomically.

:func:`frame_writer` is the one writer of the package's videos (the renderer's clips, the overlay):
frames go to a temporary file or folder beside the target, which takes the target's name only once
every frame is written; an interrupted or failed write leaves the target as it was and no temporary
file behind. An existing target is refused (:class:`~chainspace.errors.OutputExistsError`) unless
``overwrite``; the check is made again just before the rename, since another process may have
created it meanwhile.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..errors import ChainspaceError, OutputExistsError, VideoError, is_real
from ..io.results import _umask, check_writable

__all__ = ["FrameWriter", "frame_writer", "VIDEO_SUFFIXES"]

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".avi")  # what OpenCV's mp4v encoder writes
_IMAGE_SUFFIX = ".png"  # lossless: an image folder is what a benchmark or a test reads back exactly


class FrameWriter:
    """Writes BGR ``uint8`` frames (H, W, 3) of one size; made by :func:`frame_writer`."""

    def __init__(self, target: Path, tmp: Path, fps: float, size: tuple[int, int]) -> None:
        self.target, self.size, self.count = target, size, 0
        self._tmp = tmp
        self._video = None
        if target.suffix.lower() in VIDEO_SUFFIXES:
            import cv2

            self._video = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
            if not self._video.isOpened():
                raise VideoError(f"cannot write {target}: OpenCV has no mp4v encoder for {target.suffix}")

    def write(self, img: np.ndarray) -> None:
        """Append one frame (BGR ``uint8``, the writer's size)."""
        import cv2

        w, h = self.size
        if img.shape[:2] != (h, w):
            raise VideoError(f"{self.target}: frame {self.count} is {img.shape[1]} x {img.shape[0]} px, "
                             f"the video is {w} x {h}")
        if self._video is not None:
            self._video.write(img)
        elif not cv2.imwrite(str(self._tmp / f"frame_{self.count:05d}{_IMAGE_SUFFIX}"), img):
            raise VideoError(f"cannot write frame {self.count} of {self.target} (disk full?)")
        self.count += 1

    def _release(self) -> None:
        if self._video is not None:
            self._video.release()


def _replace(tmp: Path, target: Path, overwrite: bool) -> None:
    """Move ``tmp`` to ``target``; an existing target (file or folder, allowed by ``overwrite``) is set
    aside first and removed only once the new one is in place."""
    check_writable([target], overwrite)  # another process may have created it meanwhile
    if not target.is_dir():  # a file (or nothing): os.replace swaps a file atomically
        if tmp.is_dir() and target.exists():
            target.unlink()
        os.replace(tmp, target)
        return
    aside = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
    os.replace(target, aside / target.name)
    try:
        os.replace(tmp, target)
    except BaseException:
        os.replace(aside / target.name, target)
        raise
    finally:
        shutil.rmtree(aside, ignore_errors=True)


@contextlib.contextmanager
def frame_writer(target: str | os.PathLike, fps: float, size: tuple[int, int], *,
                 overwrite: bool = False) -> Iterator[FrameWriter]:
    """Open ``target`` for frames of ``size`` = (width, height) px at ``fps`` frames per second.

    ``target`` ending in ``.mp4``, ``.m4v``, ``.mov`` or ``.avi``: a video (codec ``mp4v``; MPEG-4 frames
    have even sizes, so an odd width or height loses its last column or row); without a suffix: a folder
    of ``frame_00000.png``, ``frame_00001.png``, ... (which :func:`~chainspace.video.reader.open_video`
    reads back in order). Yields a :class:`FrameWriter`; the target appears when the block completes.
    Raises :class:`~chainspace.errors.OutputExistsError` when ``target`` exists and ``overwrite`` is
    False, and :class:`~chainspace.errors.VideoError` for another suffix or a frame of another size.
    """
    target = Path(target)
    suffix = target.suffix.lower()
    if suffix and suffix not in VIDEO_SUFFIXES:
        raise VideoError(f"{target}: write a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of images (a name "
                         "without a suffix)")
    if not (is_real(fps) and fps > 0):
        raise VideoError(f"{target}: fps must be a finite number > 0 (frames per second), not {fps!r}")
    check_writable([target], overwrite)
    if suffix and target.is_dir():
        raise OutputExistsError(f"{target} is a folder; give a file name such as {target / ('video' + suffix)}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        # the temporary name keeps the target's suffix: OpenCV picks the container from it
        if suffix:
            fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".part{target.suffix}", dir=target.parent)
            os.close(fd)
            tmp = Path(name)
        else:
            tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent))
        os.chmod(tmp, (0o777 if tmp.is_dir() else 0o666) & ~_umask())  # mkstemp and mkdtemp keep others out
    except OSError as exc:
        raise ChainspaceError(f"cannot write {target}: {exc.strerror or exc}") from None
    writer = None
    try:
        writer = FrameWriter(target, tmp, float(fps), (int(size[0]), int(size[1])))
        yield writer
        writer._release()
        _replace(tmp, target, overwrite)
    finally:
        if writer is not None:
            writer._release()
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                tmp.unlink()
