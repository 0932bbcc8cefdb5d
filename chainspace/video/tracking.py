"""Points of a chain followed through a video: pyramidal Lucas-Kanade with a forward-backward check.

The user places the points in one or more key frames (:mod:`chainspace.video.keyframes`). From the
first key frame on, every point is carried from frame to frame by OpenCV's pyramidal Lucas-Kanade
(:func:`cv2.calcOpticalFlowPyrLK`), which matches the ``window`` x ``window`` patch around the point.
Each step is then refined by aligning the point's patch from its key frame (rotation and shift,
OpenCV's ECC), so that frame-to-frame errors do not add up where the surface keeps its look. Each
step is checked by tracking back to the previous frame: a point that does not come back within
``fb_max_px`` (or that leaves the image) is lost, NaN with confidence 0, until a later key frame places
it again. A later key frame re-anchors the points it gives; the distance between where the tracker had
carried a point and where the key frame puts it is the drift accumulated since the previous anchor,
reported in :attr:`TrackResult.drift`. Points on textureless surfaces slide along them without failing
the forward-backward check: the drift at re-anchors is the honest measure of that.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import VideoError, is_real
from ..progress import progress_reporter
from .keyframes import Keyframes, load_keyframes, point_names
from .reader import Video, open_video

__all__ = ["TrackResult", "track_points", "track_video"]


@dataclass
class TrackResult:
    """Tracks of a chain's points in a video.

    Attributes
    ----------
    tracks : ndarray (F, J, 2)
        Image positions, pixels (x right, y down), NaN before a point's first key frame and where lost.
    confidence : ndarray (F, J)
        In [0, 1]: 1 at key frames; ``(1 - (e / fb_max_px)**2) * t`` for a forward-backward error of
        ``e`` px and a texture factor ``t`` (low on plain surfaces and along edges, where points
        slide: see ``texture_eig`` of :func:`track_points`); 0 where lost.
    names : list of str
        The points, in the order of the tracks' second axis (a chain's joints when a chain was given).
    fps : float
        Frames per second of the video.
    image_size : (int, int)
        ``(width, height)`` of the frames, pixels: pass it on as ``image_size=`` (or to
        :meth:`camera`) for the pinhole camera of :func:`chainspace.reconstruct` and
        :func:`chainspace.fit_joint_angles`.
    drift : dict
        ``{frame: {name: px}}`` at each key frame that places a point again: the distance between the
        tracked position and the one the key frame gives, NaN where the point had been lost (or
        hidden) before.
    keyframes : dict
        The key frames used (frame -> name -> (x, y) or None).
    source : Path or None
        The video.
    seconds : float
        Wall time of the tracking (decoding included).
    """

    tracks: np.ndarray
    confidence: np.ndarray
    names: list[str]
    fps: float
    image_size: tuple[int, int]
    drift: dict[int, dict[str, float]] = field(default_factory=dict)
    keyframes: Keyframes = field(default_factory=dict)
    source: Path | None = None
    seconds: float = float("nan")

    @property
    def n_frames(self) -> int:
        return int(self.tracks.shape[0])

    @property
    def lost_fraction(self) -> float:
        """Share of (frame, point) pairs from each point's first key frame on that have no position."""
        started = np.zeros(self.tracks.shape[:2], bool)
        for f, points in self.keyframes.items():
            for name in points:
                started[f:, self.names.index(name)] = True
        if not started.any():
            return float("nan")
        return float(np.isnan(self.tracks[..., 0])[started].mean())

    @property
    def max_drift_px(self) -> float:
        """Largest drift measured at a re-anchor, pixels (NaN if there was none)."""
        values = [d for points in self.drift.values() for d in points.values() if np.isfinite(d)]
        return max(values) if values else float("nan")

    def camera(self, intrinsics: Any = None, *, fov_deg: float | None = None) -> Any:
        """The video's :class:`chainspace.PinholeCamera`: ``intrinsics`` (matrix, camera or calibration file)
        checked against the frame size, or a camera of horizontal field of view ``fov_deg`` degrees."""
        from ..cameras.pinhole import PinholeCamera, as_camera

        if fov_deg is not None:
            return PinholeCamera.from_fov(*self.image_size, fov_deg)
        if intrinsics is None:
            raise VideoError("give the camera's intrinsics (a matrix or calibration file) or fov_deg")
        return as_camera(intrinsics, self.image_size)

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the tracks and confidences as CSV (``frame,joint,x,y,confidence``), read back by
        :func:`chainspace.load_tracks`. Refuses to replace a file unless ``overwrite``."""
        from ..io.tracks import save_tracks

        return save_tracks(path, self.tracks, self.names, self.confidence, format="csv", overwrite=overwrite)

    def __repr__(self) -> str:
        w, h = self.image_size
        drift = f", max drift at re-anchors {self.max_drift_px:.2f} px" if self.drift else ""
        return (f"TrackResult({self.n_frames} frames x {len(self.names)} points, {w}x{h} px, {self.fps:g} fps, "
                f"lost {100 * self.lost_fraction:.1f}%{drift})")


def _chain_names(chain: Any) -> list[str] | None:
    if chain is None:
        return None
    if isinstance(chain, (str, os.PathLike)):
        from ..io.descriptions import load_chain

        chain = load_chain(str(chain))
    return list(chain.joints)


def _check_options(window: Any, levels: Any, fb_max_px: Any) -> None:
    if not (isinstance(window, (int, np.integer)) and not isinstance(window, bool) and window >= 5 and window % 2):
        raise VideoError(f"window must be an odd number of pixels >= 5, not {window!r}")
    if not (isinstance(levels, (int, np.integer)) and not isinstance(levels, bool) and 0 <= levels <= 8):
        raise VideoError(f"levels must be an integer from 0 to 8 (pyramid levels above the full image), "
                         f"not {levels!r}")
    if not (is_real(fb_max_px) and fb_max_px > 0):
        raise VideoError(f"fb_max_px must be a finite number > 0 (pixels), not {fb_max_px!r}")


def default_window(height_px: int) -> int:
    """The tracking patch's side (odd, px) for images ``height_px`` rows high: 21 up to 480 rows, then
    growing with the square root of the height (31 at 1080 rows).

    Why not in proportion to the image: a patch 2.25 times as wide at 1080 rows (47 px) holds more of
    the background and of neighbouring links as the robot turns; a fixed 21 px patch holds too little of
    a marker seen larger and lost it (rendered UR10 at 1920 x 1080, 240 frames: 21 px lost 36 % of the
    points' frames, 31 px none, 0.9 px RMS; the milling arm 0.27 -> 0.21 px RMS; 41 px drifted more on
    both)."""
    side = int(21 * max(1.0, float(height_px) / 480) ** 0.5)
    return side + 1 - side % 2


def track_points(video: Video | str | os.PathLike, keyframes: str | os.PathLike | Mapping[Any, Any], *,
                 chain: Any = None, window: int | None = None, levels: int = 3, fb_max_px: float = 1.0,
                 texture_eig: float = 0.02, fps: float | None = None, max_iter: int = 30, eps_px: float = 0.01,
                 refine: bool = True, progress: bool | Callable[[int, int], None] = False) -> TrackResult:
    """Track the points placed in ``keyframes`` through ``video``.

    Parameters
    ----------
    video
        A :class:`~chainspace.video.reader.Video` or the path of a video file or image folder.
    keyframes
        Key-frame JSON file or mapping: ``{frame: {name: [x, y] px or None}}`` (see
        :mod:`chainspace.video.keyframes`).
    chain
        A :class:`chainspace.KinematicChain` or its name/description file: the tracks then have the
        chain's joints, in its order (points no key frame gives stay NaN, with a warning), and a key
        frame naming another point is an error.
    window
        Side of the square patch matched around each point, pixels (odd). None (default):
        :func:`default_window` of the video's height, 21 px up to 480 rows and more above (31 px at
        1080 rows).
    levels
        Pyramid levels above the full image (OpenCV's ``maxLevel``): motions up to about
        ``window / 2 * 2**levels`` px per frame are followed.
    fb_max_px
        A point whose forward-then-backward track misses its start by more than this is lost, pixels.
    texture_eig
        How much texture a patch needs for a confident track: the confidence's texture factor
        ``e / (e + texture_eig)`` is 1/2 where the smallest eigenvalue ``e`` of the patch's gradient
        matrix (OpenCV's normalised value, 8-bit images) equals it. Random texture gives 0.01 to 0.2,
        a straight edge 0.001 to 0.006, a plain surface 0 (lost).
    fps
        Frame rate for an image folder (or replacing a file's).
    max_iter, eps_px
        Lucas-Kanade's stopping rule per pyramid level: iterations, and update size in pixels.
    refine
        After each Lucas-Kanade step, align the point's patch from its last key frame to the frame
        (rotation and shift, OpenCV's ECC), starting from the LK position. Frame-to-frame steps add up
        small errors (a rotating patch biases LK's translation); the key-frame patch does not. Where
        the patch no longer matches (correlation below 0.8, or more than ``max(2, window / 4)`` px
        from the LK position: a turned or occluded surface) the LK position stands.
    progress
        True: a progress bar on stderr (plain lines when it is not a terminal); a function
        ``progress(done, total)``; False: quiet.

    Returns
    -------
    TrackResult
    """
    import warnings

    import cv2

    _check_options(21 if window is None else window, levels, fb_max_px)  # None: chosen from the video's size
    if not (is_real(texture_eig) and texture_eig >= 0):
        raise VideoError(f"texture_eig must be a finite number >= 0, not {texture_eig!r}")
    own = not isinstance(video, Video)
    vid = open_video(video, fps) if own else video
    try:
        allowed = _chain_names(chain)
        kf = load_keyframes(keyframes, names=allowed, image_size=vid.size, frame_count=vid.frame_count)
        names = point_names(kf, allowed)
        never = [n for n in names if not any(n in pts for pts in kf.values())]
        if never:
            warnings.warn(f"no key frame places {', '.join(never)}: their tracks are empty (NaN)", stacklevel=2)
        index = {n: j for j, n in enumerate(names)}
        window = default_window(vid.size[1]) if window is None else window
        t0 = time.perf_counter()
        tracks, conf, drift = _run(vid, kf, index, window, levels, fb_max_px, texture_eig, max_iter, eps_px,
                                     progress, cv2, refine)
        seconds = time.perf_counter() - t0
    finally:
        if own:
            vid.close()
    return TrackResult(tracks, conf, names, vid.fps, vid.size, drift, kf, vid.path, seconds)


def _run(vid: Video, kf: Keyframes, index: dict[str, int], window: int, levels: int, fb_max_px: float,
         texture_eig: float, max_iter: int, eps_px: float, progress: Any, cv2: Any, refine: bool = False
         ) -> tuple[np.ndarray, np.ndarray, dict[int, dict[str, float]]]:
    F, J = vid.frame_count, len(index)
    w, h = vid.size
    tracks = np.full((F, J, 2), np.nan)
    conf = np.zeros((F, J))
    drift: dict[int, dict[str, float]] = {}
    pts = np.zeros((J, 2), np.float32)
    alive = np.zeros(J, bool)
    placed = np.zeros(J, bool)  # given by a key frame so far
    weight = np.zeros(J)
    win = (window, window)
    lk = dict(winSize=win, maxLevel=levels,
              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, max_iter, eps_px))
    first = min(kf)
    prev = None
    done = first
    templates: list[Any] = [None] * J
    angles = np.zeros(J)
    with progress_reporter(progress, F, f"tracking {J} points") as report:
        for f, image in enumerate(vid.frames(first), start=first):
            gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
            if prev is not None and alive.any():
                idx = np.flatnonzero(alive)
                p0 = pts[idx].reshape(-1, 1, 2)
                # the forward step also returns each patch's smallest gradient eigenvalue: low on plain
                # surfaces and along edges, where LK slides (the aperture problem) without failing
                p1, st1, eig = cv2.calcOpticalFlowPyrLK(prev, gray, p0, None, flags=cv2.OPTFLOW_LK_GET_MIN_EIGENVALS,
                                                        **lk)
                back, st2, _ = cv2.calcOpticalFlowPyrLK(gray, prev, p1, None, **lk)
                p1, back = p1.reshape(-1, 2), back.reshape(-1, 2)
                fb = np.linalg.norm(back - p0.reshape(-1, 2), axis=1)
                inside = (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
                ok = st1.ravel().astype(bool) & st2.ravel().astype(bool) & (fb <= fb_max_px) & inside
                ok &= np.isfinite(p1).all(axis=1)
                pts[idx] = p1
                alive[idx] = ok
                eig = np.nan_to_num(eig.ravel())
                texture = eig / np.maximum(eig + texture_eig, 1e-12)
                weight[idx] = np.where(ok, (1.0 - (fb / fb_max_px) ** 2) * texture, 0.0)
                if refine:
                    _refine(gray, idx[ok], pts, templates, angles, window, cv2)
            if f in kf:
                _anchor(f, kf[f], index, pts, alive, weight, drift, placed)
                if refine:
                    for name, xy in kf[f].items():
                        j = index[name]
                        templates[j] = None if xy is None else cv2.getRectSubPix(gray, win, tuple(map(float, xy)))
                        angles[j] = 0.0
            tracks[f, alive] = pts[alive]
            conf[f, alive] = np.clip(weight[alive], 0.0, 1.0)
            prev = gray
            done = f + 1
            if done % 10 == 0:
                report(done)
        report(done)
    if done < F:  # the file held fewer frames than its header said
        tracks, conf = tracks[:done], conf[:done]
    return tracks, conf, drift


def _refine(gray: np.ndarray, idx: np.ndarray, pts: np.ndarray, templates: list, angles: np.ndarray,
            window: int, cv2: Any, min_cc: float = 0.8) -> None:
    """Align each point's key-frame patch to this frame (rotation and shift, OpenCV's ECC) from the
    LK position: frame-to-frame steps add up small errors (rotation biases LK's translation), the
    key-frame patch does not. Points whose patch no longer matches keep the LK position."""
    h, w = gray.shape
    c = (window - 1) / 2
    for j in idx:
        if templates[j] is None:
            continue
        x, y = pts[j]
        ox, oy = int(round(x)) - window, int(round(y)) - window
        if ox < 0 or oy < 0 or ox + 2 * window + 1 > w or oy + 2 * window + 1 > h:
            continue
        roi = gray[oy:oy + 2 * window + 1, ox:ox + 2 * window + 1]
        a = angles[j]
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        warp = np.hstack([R, (np.array([x - ox, y - oy]) - R @ [c, c])[:, None]]).astype(np.float32)
        try:
            cc, warp = cv2.findTransformECC(templates[j], roi, warp, cv2.MOTION_EUCLIDEAN,
                                            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-4), None, 1)
        except cv2.error:
            continue
        p = warp[:, :2] @ [c, c] + warp[:, 2] + [ox, oy]
        if cc >= min_cc and np.hypot(*(p - pts[j])) <= max(2.0, window / 4):
            pts[j] = p
            angles[j] = np.arctan2(warp[1, 0], warp[0, 0])


def _anchor(f: int, points: dict[str, tuple[float, float] | None], index: dict[str, int], pts: np.ndarray,
            alive: np.ndarray, weight: np.ndarray, drift: dict[int, dict[str, float]], placed: np.ndarray) -> None:
    """Place the key frame's points; measure how far the tracker had carried them from there."""
    measured: dict[str, float] = {}
    for name, xy in points.items():
        j = index[name]
        if xy is None:
            alive[j] = False
            continue
        if placed[j]:  # a point given for the first time has no drift to measure
            measured[name] = float(np.hypot(*(pts[j] - xy))) if alive[j] else float("nan")
        placed[j] = True
        pts[j] = xy
        alive[j] = True
        weight[j] = 1.0
    if measured:
        drift[f] = measured


def track_video(video_path: str | os.PathLike, keyframes: str | os.PathLike | Mapping[Any, Any],
                out: str | os.PathLike | None = None, *, chain: Any = None, fps: float | None = None,
                overwrite: bool = False, progress: bool | Callable[[int, int], None] = True,
                **options: Any) -> TrackResult:
    """Track the key frames' points through a video and write them as CSV: ``chainspace track`` in Python.

    ``out`` (optional) is the CSV (``frame,joint,x,y,confidence``, read by :func:`chainspace.load_tracks`);
    it is checked before the work starts and is not replaced unless ``overwrite``. ``options`` go to
    :func:`track_points` (``window``, ``levels``, ``fb_max_px``, ...).
    """
    from ..io.results import check_writable

    if out is not None:
        check_writable([out], overwrite)
    result = track_points(video_path, keyframes, chain=chain, fps=fps, progress=progress, **options)
    if out is not None:
        result.save(out, overwrite=overwrite)
    return result
