"""A result drawn over its footage: :func:`draw_overlay` (``chainspace overlay``).

Every frame of the video gets the fitted robot (a :class:`~chainspace.robot.result.JointFit`) or the
reconstructed chain (a :class:`~chainspace.reconstruction.pipeline.Reconstruction`) reprojected through
the result's own camera, with the 2D tracks and the reprojection error of every point:

* bones as lines and joints as filled circles (green): where the result puts the chain in the image;
* tracks as crosses (orange): what was seen;
* a red line from each track to its reprojection, and the frame's RMS reprojection error (pixels, the
  tracks' confidences as weights, as the fit weighs them) written in the corner.

How a result maps 3D to pixels is the result's own: a JointFit's points come from Pinocchio forward
kinematics of the fitted ``q``, seen by :meth:`JointFit.reprojected` (the pinhole camera
``intrinsics`` + ``camera_pose``, lens distortion included, when the fit was perspective; else the
weak-perspective ``cameras`` and ``translations_2d``); a Reconstruction's poses go through its
weak-perspective cameras (:func:`chainspace.cameras.weak.project`), or with intrinsics its
``points_camera`` through the pinhole camera, as :meth:`Reconstruction.reprojection_error` measures.

``side_by_side=True`` adds a panel of the video's size on the right: the 3D points drawn
orthographically from a fixed viewpoint, from the side: the first frame's camera turned a quarter turn
about the vertical (a robot's base z axis; the image's vertical for a reconstruction) and made level, so
that the panel shows the depth the footage cannot; one scale for the whole clip.

Frames are streamed (one in memory at a time) and written as MP4 (``mp4v``) or a folder of PNGs by
:func:`chainspace.video.writer.frame_writer`: to a temporary file next to the output, renamed into place
only once complete.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import TrackError, VideoError, is_real
from ..io.results import check_writable
from ..progress import progress_reporter
from .reader import open_video
from .writer import VIDEO_SUFFIXES, frame_writer

__all__ = ["draw_overlay"]

# BGR colours
_CHAIN = (80, 220, 60)
_TRACK = (0, 160, 255)
_ERROR = (40, 40, 235)
_TEXT = (255, 255, 255)
_PANEL = (40, 36, 32)

_SHIFT = 4  # cv2 drawing with 4 fractional bits: points are placed to 1/16 px, not rounded to whole pixels


# ---------------------------------------------------------------------------------------- reading frames
def _frames(video: Any, fps: float | None = None) -> Any:
    """An open video: a path (file or image folder) for :func:`open_video`, or a Video already open."""
    if all(hasattr(video, a) for a in ("fps", "size", "frame_count", "__iter__")):
        return video
    if fps is None and Path(video).is_dir():
        fps = 30.0  # only the overlay's playback rate: nothing is fitted from it
    return open_video(video, fps=fps)


# ---------------------------------------------------------------------------------------- the result in pixels
@dataclass
class _Scene:
    """What is drawn: reprojection (F, J, 2) px, tracks (F, J, 2) px or None, weights (F, J), points (F, J, 3)
    for the 3D panel, view (3, 3) rotation for the panel, segments (L, 2) joint indices."""

    reprojection: np.ndarray
    tracks: np.ndarray | None
    weights: np.ndarray | None
    points: np.ndarray
    view: np.ndarray
    segments: np.ndarray


def _camera_rotation(cameras: np.ndarray | None) -> np.ndarray:
    """The rotation (rows: image right, image down, depth) of the first weak-perspective camera ``s R[:2]``."""
    from ..cameras.weak import complete_rotation

    if cameras is None or not np.isfinite(cameras[0]).all():
        return np.eye(3)
    rows = np.asarray(cameras[0], float)
    return complete_rotation(rows / np.linalg.norm(rows, axis=-1, keepdims=True))


def _side_view(R0: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """The panel's rotation (rows: right, down, forward): the camera R0 (same rows) turned a quarter turn
    about ``up`` (default the image's upward axis), looking level, so the panel shows the depth the footage
    cannot."""
    up = -R0[1] if up is None else np.asarray(up, float) / np.linalg.norm(up)
    # the view direction made level; a camera looking straight down has none: its right axis then
    level = [v - (v @ up) * up for v in (R0[2], R0[0])]
    f = level[0] if np.linalg.norm(level[0]) > 1e-6 else level[1]
    f = f / np.linalg.norm(f)
    side = np.cross(up, f)
    return np.array([np.cross(-up, side), -up, side])


def _scene(result: Any) -> _Scene:
    """The result's chain in pixels, seen by its own camera (module docstring)."""
    if getattr(result, "chain", None) is None or not (hasattr(result, "q") or hasattr(result, "poses")):
        raise TrackError(f"draw_overlay needs a JointFit or a Reconstruction (chainspace.load_results), not "
                         f"{type(result).__name__}")
    chain = result.chain
    segments = np.array([[chain.joint_index(a), chain.joint_index(b)] for a, b in chain.links], int).reshape(-1, 2)
    confidence = getattr(result, "confidence", None)
    if hasattr(result, "q") and hasattr(result, "joint_names"):  # a JointFit
        base = result.kinematics().positions(np.asarray(result.q, float))
        uv = dataclasses.replace(result, positions_base=base).reprojected()
        if uv is None:
            raise TrackError("the joint fit has no camera (fitted without 2D tracks, or refine=False): "
                             "there is nothing to draw over the footage")
        R0 = (np.asarray(result.camera_pose[0], float) if result.camera_pose is not None
              else _camera_rotation(result.cameras))
        return _Scene(uv, result.tracks, confidence, base, _side_view(R0, up=[0.0, 0.0, 1.0]), segments)  # z up
    # a Reconstruction
    intrinsics = getattr(result, "intrinsics", None)
    if intrinsics is not None and getattr(result, "points_camera", None) is not None:
        uv = intrinsics.project(result.points_camera)
        R0 = np.eye(3)  # the poses are in the camera's axes
    else:
        from ..cameras.weak import project

        uv = project(result.poses, result.cameras, result.translations)
        R0 = _camera_rotation(np.asarray(result.cameras, float))
    return _Scene(uv, result.tracks, confidence, np.asarray(result.poses, float), _side_view(R0), segments)


def _tracks(tracks: Any, chain: Any, n_frames: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Tracks given to draw_overlay: a track file (any format load_tracks reads) or an array (F, J, 2)."""
    if isinstance(tracks, (str, os.PathLike)):
        from ..io.tracks import load_tracks

        arr, conf, _ = load_tracks(tracks, chain)
        where = f"{tracks}: "
    else:
        arr, conf, where = np.asarray(tracks, float), None, ""
    want = (n_frames, chain.n_joints, 2)
    if arr.shape != want:
        raise TrackError(f"{where}tracks have shape {arr.shape}, expected {want}: {n_frames} frames of the "
                         f"{chain.n_joints} points of {chain.name}")
    return arr, conf


def _rms_px(scene: _Scene) -> np.ndarray:
    """(F,) RMS reprojection error per frame, px (NaN where no point is seen)."""
    from ..robot.solver import _rms_per_frame

    if scene.tracks is None:
        return np.full(len(scene.reprojection), np.nan)
    d = np.linalg.norm(scene.tracks - scene.reprojection, axis=-1)
    seen = np.isfinite(d)
    w = seen * (1.0 if scene.weights is None else np.nan_to_num(np.asarray(scene.weights, float)))
    return _rms_per_frame(np.where(seen, d, 0.0), w)


# ---------------------------------------------------------------------------------------- drawing
def _fixed(points: np.ndarray) -> np.ndarray:
    """Pixel coordinates as cv2's fixed-point integers (``_SHIFT`` fractional bits), clipped to int32."""
    return np.clip(np.round(points * (1 << _SHIFT)), -2**28, 2**28).astype(np.int32)


def _draw_chain(img: np.ndarray, uv: np.ndarray, segments: np.ndarray, thick: int) -> None:
    import cv2

    ends = uv[segments]  # (L, 2, 2)
    ends = ends[np.isfinite(ends).all((1, 2))]
    if len(ends):
        cv2.polylines(img, list(_fixed(ends)), False, _CHAIN, thick, cv2.LINE_AA, _SHIFT)
    for p in _fixed(uv[np.isfinite(uv).all(-1)]):
        cv2.circle(img, tuple(int(v) for v in p), (2 * thick + 1) << _SHIFT, _CHAIN, -1, cv2.LINE_AA, _SHIFT)


def _draw_tracks(img: np.ndarray, tracks: np.ndarray, uv: np.ndarray, thick: int) -> None:
    import cv2

    seen = np.isfinite(tracks).all(-1)
    pairs = np.stack([tracks, uv], 1)[seen & np.isfinite(uv).all(-1)]  # (n, 2, 2): track -> reprojection
    if len(pairs):
        cv2.polylines(img, list(_fixed(pairs)), False, _ERROR, max(1, thick // 2), cv2.LINE_AA, _SHIFT)
    for p in np.round(np.clip(tracks[seen], -1e6, 1e6)).astype(int):
        cv2.drawMarker(img, (int(p[0]), int(p[1])), _TRACK, cv2.MARKER_CROSS, 6 * thick + 2, thick, cv2.LINE_AA)


def _text(img: np.ndarray, text: str, row: int, thick: int) -> None:
    """White text on a dark box (readable on any footage), at line ``row`` from the top left."""
    import cv2

    scale = 0.4 * thick
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    x, y = 4 * thick, (row + 1) * (h + base + 6 * thick)
    cv2.rectangle(img, (x - 2 * thick, y - h - 2 * thick), (x + w + 2 * thick, y + base), (0, 0, 0), -1)
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT, thick, cv2.LINE_AA)


class _Panel:
    """The 3D view: every frame's points turned by ``view`` and drawn orthographically, one scale for the clip."""

    def __init__(self, scene: _Scene, size: tuple[int, int], thick: int) -> None:
        self.xy = (scene.points @ scene.view.T)[..., :2]
        lo, hi = np.nanmin(self.xy, axis=(0, 1)), np.nanmax(self.xy, axis=(0, 1))
        w, h = size
        extent = np.maximum(hi - lo, 1e-12)
        self.scale = 0.8 * min(w / extent[0], h / extent[1])
        self.offset = np.array([w, h]) / 2 - self.scale * (lo + hi) / 2
        self.segments, self.thick = scene.segments, thick
        self.background = np.empty((h, w, 3), np.uint8)
        self.background[:] = _PANEL
        _text(self.background, "3D, side view", 0, thick)

    def draw(self, f: int) -> np.ndarray:
        img = self.background.copy()  # a copy is cheaper than filling a new image every frame
        _draw_chain(img, self.xy[f] * self.scale + self.offset, self.segments, self.thick)
        return img


def _draw_frame(img: np.ndarray, scene: _Scene, f: int, rms: float, thick: int) -> None:
    uv = scene.reprojection[f]
    _draw_chain(img, uv, scene.segments, thick)
    if scene.tracks is not None:
        _draw_tracks(img, scene.tracks[f], uv, thick)
    _text(img, f"frame {f}  RMS " + ("-" if not np.isfinite(rms) else f"{rms:.2f} px"), 0, thick)


def draw_overlay(video: Any, result: Any, *, tracks: Any = None, out: str | os.PathLike = "overlay.mp4",
                 side_by_side: bool = False, overwrite: bool = False, progress: bool = True,
                 fps: float | None = None) -> Path:
    """Draw a result over every frame of its video and write an MP4 (or a folder of PNGs); return its path.

    Drawn per frame: bones and joints reprojected through the result's camera (green), the tracks
    (orange crosses), a red line from each track to its reprojection, and the frame's RMS reprojection
    error in pixels (confidence weighted). Raises :class:`~chainspace.errors.TrackError` when the video
    cannot be read or its frame count differs from the result's, and
    :class:`~chainspace.errors.OutputExistsError` when ``out`` exists and ``overwrite`` is False.

    Parameters
    ----------
    video
        The footage: a video file (MP4, MOV, AVI: whatever OpenCV reads), a folder of numbered images
        (``f9.png`` before ``f10.png``), or an opened video. It must have exactly as many frames as the
        result.
    result
        A joint fit (:class:`~chainspace.robot.result.JointFit`) or a reconstruction
        (:class:`~chainspace.reconstruction.pipeline.Reconstruction`), or the path of one saved by
        ``chainspace fit`` / ``reconstruct`` (read with :func:`~chainspace.io.results.load_results`).
    tracks
        The 2D tracks to draw (F, J, 2) px, or a track file :func:`~chainspace.load_tracks` reads;
        default: the tracks the result was fitted to.
    out
        The output video (``.mp4``, ``.m4v``, ``.mov`` or ``.avi``; codec mp4v), or without a suffix a
        folder of ``frame_00000.png``... (lossless), written atomically. An existing output is replaced
        only with ``overwrite=True``. MPEG-4 frames have even sizes: an odd width or height loses its
        last column or row.
    side_by_side
        Add a 3D view panel of the video's size on the right (the output is twice as wide).
    progress
        A progress bar on stderr (plain lines when stderr is not a terminal).
    fps
        Frame rate of the output; default the video file's own, 30 for a folder of images.
    """
    target = Path(out)
    if target.suffix and target.suffix.lower() not in VIDEO_SUFFIXES:
        raise TrackError(f"{target}: the overlay is a video; give a name ending in {', '.join(VIDEO_SUFFIXES)}, "
                         "or a name without a suffix for a folder of PNG images")
    if fps is not None and not (is_real(fps) and fps > 0):
        raise TrackError(f"fps must be a finite number > 0 (frames per second), not {fps!r}")
    check_writable([target], overwrite)  # refuse before any work
    if isinstance(result, (str, os.PathLike)):
        from ..io.results import load_results

        result = load_results(result)
    scene = _scene(result)
    n = len(scene.reprojection)
    if tracks is not None:
        scene.tracks, scene.weights = _tracks(tracks, result.chain, n)
    frames = _frames(video, fps)
    name = getattr(frames, "path", video)
    if frames.frame_count is not None and frames.frame_count != n:
        raise TrackError(f"{name}: the video has {frames.frame_count} frames but the result has {n}; "
                         "give the video the result was computed from")
    width, height = frames.size
    camera = getattr(result, "intrinsics", None)
    camera_size = getattr(camera, "image_size", None)
    if camera_size is not None and tuple(camera_size) != (width, height):
        raise TrackError(f"{name}: the video is {width} x {height} px but the result's camera is "
                         f"{camera_size[0]} x {camera_size[1]} px")
    rms = _rms_px(scene)
    thick = max(1, round(min(width, height) / 360))
    panel = _Panel(scene, (width, height), thick) if side_by_side else None
    size = (2 * width if side_by_side else width, height)
    seen = 0
    with frame_writer(target, frames.fps, size, overwrite=overwrite) as writer, \
            progress_reporter(progress, n, "overlay") as report:
        for f, img in enumerate(frames):
            if f >= n:
                raise TrackError(f"{name}: the video has more frames than the result's {n}; give the video "
                                 "the result was computed from")
            if img.shape[:2] != (height, width):
                raise VideoError(f"{name}: frame {f} is {img.shape[1]} x {img.shape[0]} px, the first "
                                                   f"is {width} x {height}")
            img = np.ascontiguousarray(img)
            _draw_frame(img, scene, f, rms[f], thick)
            writer.write(img if panel is None else np.hstack([img, panel.draw(f)]))
            seen += 1
            report(seen)
        if seen != n:
            raise TrackError(f"{name}: the video has {seen} frames but the result has {n}; give the video the "
                             "result was computed from")
    return target
