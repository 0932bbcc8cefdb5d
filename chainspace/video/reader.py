"""Frames of a video file (MP4, MOV, AVI, ... through OpenCV) or of a folder of numbered images.

:func:`open_video` returns a :class:`Video`: its frame rate, image size and frame count are read from
the file (a folder of images has no rate: give ``fps``), and its frames are streamed one at a time as
BGR ``uint8`` arrays (H, W, 3), never all loaded. Anything that cannot be read raises
:class:`chainspace.errors.VideoError` naming the file and, where it matters, the frame.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import VideoError, is_real

__all__ = ["Video", "open_video", "IMAGE_SUFFIXES", "natural_key"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def natural_key(name: str) -> tuple:
    """Sort key that orders the numbers inside names by value: ``f9.png`` before ``f10.png``."""
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part.lower())
                 for part in re.split(r"(\d+)", name) if part)


def _cv2() -> Any:
    import cv2

    return cv2


def _check_fps(fps: Any, path: Path) -> float:
    if not (is_real(fps) and fps > 0):
        raise VideoError(f"{path}: fps must be a finite number > 0 (frames per second), not {fps!r}")
    return float(fps)


class Video:
    """A video file or image folder opened for streaming; use :func:`open_video` to make one.

    Attributes
    ----------
    path : Path
        The file or folder.
    fps : float
        Frames per second (from the file, or as given).
    size : (int, int)
        ``(width, height)`` of the frames, pixels.
    frame_count : int
        Number of frames (a video file's header count; :meth:`frames` stops early, with a warning,
        if the file holds fewer).

    Iterating gives every frame in order; :meth:`frames` gives a range; :meth:`frame` one frame.
    Frames are BGR ``uint8`` arrays (height, width, 3). Use it as a context manager
    (``with open_video(p) as video:``) or call :meth:`close` to release the decoders it holds.
    """

    def __init__(self, path: Path, fps: float, size: tuple[int, int], frame_count: int,
                 images: list[Path] | None = None) -> None:
        self.path, self.fps, self.size, self.frame_count = path, fps, size, frame_count
        self._images = images
        self._captures: set[Any] = set()

    def __repr__(self) -> str:
        kind = "image folder" if self._images is not None else "video"
        return (f"Video({str(self.path)!r}, {kind}, {self.frame_count} frames, {self.size[0]}x{self.size[1]} px, "
                f"{self.fps:g} fps)")

    def __len__(self) -> int:
        return self.frame_count

    def __iter__(self) -> Iterator[np.ndarray]:
        return self.frames()

    def __enter__(self) -> Video:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release every decoder still open (iterators left unfinished)."""
        for cap in list(self._captures):
            cap.release()
        self._captures.clear()

    def frame(self, index: int) -> np.ndarray:
        """Frame ``index`` (0-based) as BGR uint8 (H, W, 3)."""
        if not (0 <= index < self.frame_count):
            raise VideoError(f"{self.path}: frame {index} is out of range (the video has {self.frame_count} "
                             "frames, numbered from 0)")
        for image in self.frames(index, index + 1):
            return image
        raise VideoError(f"{self.path}: frame {index} cannot be read")

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        """Frames ``start`` to ``stop - 1`` (default to the end), one at a time, BGR uint8 (H, W, 3)."""
        stop = self.frame_count if stop is None else min(int(stop), self.frame_count)
        if start < 0:
            raise VideoError(f"{self.path}: the first frame must be >= 0, not {start}")
        if start >= stop:
            return iter(())
        if self._images is not None:
            return self._image_frames(start, stop)
        return self._video_frames(start, stop)

    def _image_frames(self, start: int, stop: int) -> Iterator[np.ndarray]:
        cv2 = _cv2()
        assert self._images is not None
        for i in range(start, stop):
            image = cv2.imread(str(self._images[i]), cv2.IMREAD_COLOR)
            if image is None:
                raise VideoError(f"{self._images[i]}: frame {i} of {self.path} is not a readable image")
            yield self._checked(image, i, self._images[i])

    def _video_frames(self, start: int, stop: int) -> Iterator[np.ndarray]:
        cv2 = _cv2()
        cap = cv2.VideoCapture(str(self.path))
        self._captures.add(cap)
        try:
            # grab() without decoding is cheap and exact, where seeking by frame number is not for every codec
            for i in range(start):
                if not cap.grab():
                    self._ended_early(i)
                    return
            for i in range(start, stop):
                ok, image = cap.read()
                if not ok or image is None:
                    self._ended_early(i)
                    return
                yield self._checked(image, i, self.path)
        finally:
            cap.release()
            self._captures.discard(cap)

    def _ended_early(self, index: int) -> None:
        warnings.warn(f"{self.path}: the video ends at frame {index} although its header counts "
                      f"{self.frame_count} frames", stacklevel=3)
        self.frame_count = index

    def _checked(self, image: np.ndarray, index: int, source: Path) -> np.ndarray:
        if image.ndim == 2:
            image = np.repeat(image[..., None], 3, axis=2)
        h, w = image.shape[:2]
        if (w, h) != self.size:
            raise VideoError(f"{source}: frame {index} is {w}x{h} px but the video's first frame is "
                             f"{self.size[0]}x{self.size[1]} px (every frame must have the same size)")
        return image


def _open_folder(path: Path, fps: Any) -> Video:
    cv2 = _cv2()
    images = sorted((p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                    key=lambda p: natural_key(p.name))
    if not images:
        raise VideoError(f"{path}: the folder holds no images ({', '.join(IMAGE_SUFFIXES)})")
    if fps is None:
        raise VideoError(f"{path}: a folder of images has no frame rate; give fps (--fps N, frames per second)")
    rate = _check_fps(fps, path)
    first = cv2.imread(str(images[0]), cv2.IMREAD_COLOR)
    if first is None:
        raise VideoError(f"{images[0]}: frame 0 of {path} is not a readable image")
    h, w = first.shape[:2]
    return Video(path, rate, (int(w), int(h)), len(images), images)


def _open_file(path: Path, fps: Any) -> Video:
    cv2 = _cv2()
    if path.stat().st_size == 0:
        raise VideoError(f"{path}: the file is empty")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise VideoError(f"{path}: not a video OpenCV can read (corrupt, or a codec it lacks)")
        ok, first = cap.read()
        if not ok or first is None:
            raise VideoError(f"{path}: the video holds no readable frame (corrupt or empty)")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        rate = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        if count <= 0:  # a stream without a frame count in its header: count by reading through it once
            count = 1
            while cap.grab():
                count += 1
    finally:
        cap.release()
    if fps is not None:
        rate = _check_fps(fps, path)
    elif not (np.isfinite(rate) and rate > 0):
        raise VideoError(f"{path}: the video does not say its frame rate; give fps (--fps N)")
    h, w = first.shape[:2]
    return Video(path, rate, (int(w), int(h)), count)


def open_video(path: str | os.PathLike, fps: float | None = None) -> Video:
    """Open a video file (MP4, MOV, AVI, ...) or a folder of numbered PNG/JPEG images for streaming.

    Parameters
    ----------
    path
        A video file OpenCV can decode, or a folder whose images are the frames in natural order of
        their names (``f9.png`` before ``f10.png``, with or without zero padding).
    fps
        Frames per second. Required for a folder; for a file it replaces the rate the file states.

    Raises
    ------
    VideoError
        A missing path, an empty or corrupt file, an empty folder, a missing or bad ``fps``.
    """
    p = Path(path)
    if not p.exists():
        raise VideoError(f"{p}: no such video file or image folder")
    if p.is_dir():
        return _open_folder(p, fps)
    return _open_file(p, fps)
