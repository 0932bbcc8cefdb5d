"""Synthetic monocular views of 3D motion: random low-motion camera paths, projection, pixel noise.

This reproduces the protocol of Wandt et al. (2017, Sec. 4.1): a weak-perspective camera orbits the
subject about the vertical axis, starting at a random azimuth, sweeping a small total angle over the
sequence ("low camera motion"), at a random elevation. A camera is a (2, 3) matrix ``s * R[:2]``
with ``R`` a rotation whose rows are the image right, image down and viewing directions (image y
points down, as in pixel coordinates) and ``s`` the scale in image units (px) per metre.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import TrackError

__all__ = ["orbit_cameras", "observe", "scale_for_span", "look_rotation", "swing_motion", "PinholeView",
           "static_pinhole_view", "orthographic_view", "bend_walk", "turning_walk", "out_and_back",
           "walking_direction"]

_UP = {"z": (np.array([0.0, 0, 1]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])),
       "y": (np.array([0.0, 1, 0]), np.array([0.0, 0, 1]), np.array([1.0, 0, 0]))}


def _axes(up: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        return _UP[up.lower()]
    except (KeyError, AttributeError):
        raise TrackError(f"up must be 'z' or 'y', not {up!r}") from None


def look_rotation(azimuth: Any, elevation: Any, *, up: str = "z") -> np.ndarray:
    """(..., 3, 3) rotations of cameras looking at the origin from ``azimuth`` about the up axis and
    ``elevation`` above the horizontal plane (radians). Rows: image right, image down, view direction."""
    u, h1, h2 = _axes(up)
    az, el = np.broadcast_arrays(np.asarray(azimuth, float), np.asarray(elevation, float))
    pos = (np.cos(el) * np.cos(az))[..., None] * h1 + (np.cos(el) * np.sin(az))[..., None] * h2
    pos = pos + np.sin(el)[..., None] * u
    fwd = -pos
    right = np.cross(fwd, u)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], axis=-2)


def orbit_cameras(
    n_frames: int,
    *,
    sweep_deg: float = 10.0,
    elevation_deg: float | None = None,
    start_deg: float | None = None,
    scale: float = 1.0,
    up: str = "z",
    seed: Any = None,
) -> np.ndarray:
    """(F, 2, 3) weak-perspective cameras orbiting about the vertical axis.

    The azimuth runs linearly from ``start_deg`` (random in [0, 360) when None) over ``sweep_deg``
    degrees in a random direction; the elevation is fixed, random in [0, 30] degrees when None.
    ``scale`` is image units per world unit (see :func:`scale_for_span`). Rows are orthogonal with
    norm ``scale``.
    """
    if int(n_frames) < 1:
        raise TrackError(f"n_frames must be at least 1, not {n_frames}")
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.0, 360.0) if start_deg is None else float(start_deg)
    elev = rng.uniform(0.0, 30.0) if elevation_deg is None else float(elevation_deg)
    direction = rng.choice([-1.0, 1.0])
    az = np.deg2rad(start + direction * sweep_deg * np.linspace(0.0, 1.0, int(n_frames)))
    R = look_rotation(az, np.deg2rad(elev), up=up)
    return float(scale) * R[:, :2, :]


def scale_for_span(poses: Any, span_px: float = 720.0, *, up: str = "z") -> float:
    """Camera scale (px per world unit) so the subject's extent along the up axis spans ``span_px``.

    The extent is the 98th percentile over frames of the per-frame height of the joints; a human
    filling 80 % of a 900 px tall image is ``span_px=720``.
    """
    X = np.asarray(poses, dtype=float)
    u = _axes(up)[0]
    h = X @ u
    height = np.nanpercentile(np.nanmax(h, axis=-1) - np.nanmin(h, axis=-1), 98)
    if not np.isfinite(height) or height <= 0:
        raise TrackError("poses have no vertical extent: cannot pick a camera scale")
    return float(span_px) / float(height)


def observe(
    poses: Any,
    cameras: Any,
    *,
    translations: Any = None,
    noise_px: float = 0.0,
    seed: Any = None,
) -> np.ndarray:
    """Project poses (F, J, 3) with weak-perspective cameras (F, 2, 3) into tracks (F, J, 2).

    ``translations`` (F, 2) or (2,) image offsets are added; ``noise_px`` is the standard deviation of
    Gaussian noise per image coordinate (image units).
    """
    X = np.asarray(poses, dtype=float)
    P = np.asarray(cameras, dtype=float)
    if X.ndim != 3 or X.shape[-1] != 3:
        raise TrackError(f"poses have shape {X.shape}, expected (F, J, 3)")
    if P.shape != (X.shape[0], 2, 3):
        raise TrackError(f"cameras have shape {P.shape}, expected ({X.shape[0]}, 2, 3)")
    W = X @ np.swapaxes(P, -1, -2)
    if translations is not None:
        W = W + np.broadcast_to(np.asarray(translations, float), (X.shape[0], 2))[:, None, :]
    if noise_px > 0:
        W = W + np.random.default_rng(seed).normal(scale=float(noise_px), size=W.shape)
    return W


def swing_motion(chain: Any, n_frames: int = 120, *, amplitude_deg: float = 30.0, fps: float = 30.0,
                 rest_pose: Any = None, seed: Any = None) -> np.ndarray:
    """(F, J, 3) smooth articulated motion of ``chain`` with constant bone lengths.

    Each tree bone of the rest pose swings about its own random axis by up to ``amplitude_deg``
    with a random frequency between 0.3 and 1.5 Hz: a stand-in for real motion in tests.
    """
    from scipy.spatial.transform import Rotation

    X0 = np.asarray(chain.rest_pose if rest_pose is None else rest_pose, dtype=float)
    if X0 is None or X0.shape != (chain.n_joints, 3):
        raise TrackError("swing_motion needs a rest pose (J, 3)")
    rng = np.random.default_rng(seed)
    nb = chain.n_bones
    axes = rng.normal(size=(nb, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    amp = np.deg2rad(amplitude_deg) * rng.uniform(0.3, 1.0, nb)
    freq = rng.uniform(0.3, 1.5, nb)
    phase = rng.uniform(0, 2 * np.pi, nb)
    t = np.arange(int(n_frames)) / fps
    ang = amp * np.sin(2 * np.pi * freq * t[:, None] + phase)  # (F, nb)
    rot = Rotation.from_rotvec((ang[..., None] * axes).reshape(-1, 3)).as_matrix().reshape(len(t), nb, 3, 3)
    B0 = chain.bone_vectors(X0)[:nb]
    B = np.einsum("fbij,bj->fbi", rot, B0)
    return chain.poses_from_bones(B)


# ------------------------------------------------------------------------------ static pinhole camera
@dataclass(frozen=True)
class PinholeView:
    """Where a static :class:`~chainspace.cameras.pinhole.PinholeCamera` stands: ``camera`` (the
    intrinsics, projection and distortion: the project's one camera model), rotation ``R`` (3, 3,
    rows: image right, image down, viewing direction) and translation ``t`` (3,), ``x_cam = R x + t``.
    ``center`` is the camera centre in the world."""

    camera: Any
    R: np.ndarray
    t: np.ndarray

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    def to_camera(self, points: Any) -> np.ndarray:
        return np.asarray(points, float) @ self.R.T + self.t

    def project(self, points: Any) -> np.ndarray:
        """World points (..., 3) -> pixels (..., 2) (:meth:`PinholeCamera.project`: NaN at or behind the camera)."""
        return self.camera.project(self.to_camera(points))

    def __repr__(self) -> str:
        c = self.center
        return f"PinholeView({self.camera!r}, centre=({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}))"


def static_pinhole_view(
    poses: Any,
    *,
    distance_m: float = 4.0,
    f_px: float = 750.0,
    image_size: tuple[int, int] = (640, 480),
    height_m: float = 1.5,
    azimuth_deg: float | None = None,
    dist: Any = None,
    noise_px: float = 0.0,
    up: str = "z",
    seed: Any = None,
) -> tuple[np.ndarray, PinholeView]:
    """Film world poses (F, J, 3) with one static pinhole camera: ``(tracks (F, J, 2) px, camera)``.

    The camera stands ``distance_m`` from the subject's mean position (all joints, all frames),
    measured in the ground plane, at azimuth ``azimuth_deg`` about the up axis (random when None),
    ``height_m`` above the lowest joint of the motion (the floor), and looks at the mean position
    (principal point at the image centre, square pixels, focal length ``f_px``). ``dist`` are
    OpenCV distortion coefficients (k1, k2, p1, p2[, k3]) applied to the projection. Gaussian
    noise of ``noise_px`` per coordinate is added; points at or behind the camera are NaN (points
    outside the image are kept: the tracks are what a tracker would report with the image extended).
    """
    X = np.asarray(poses, float)
    if X.ndim != 3 or X.shape[-1] != 3:
        raise TrackError(f"poses have shape {X.shape}, expected (F, J, 3)")
    if not (np.isfinite(distance_m) and distance_m > 0 and np.isfinite(f_px) and f_px > 0):
        raise TrackError(f"distance_m and f_px must be > 0, not {distance_m!r}, {f_px!r}")
    u, h1, h2 = _axes(up)
    rng = np.random.default_rng(seed)
    az = np.deg2rad(rng.uniform(0.0, 360.0) if azimuth_deg is None else float(azimuth_deg))
    target = np.nanmean(X.reshape(-1, 3), axis=0)
    floor = float(np.nanmin(X @ u))
    ground = target - (target @ u) * u
    centre = ground + distance_m * (np.cos(az) * h1 + np.sin(az) * h2) + (floor + height_m) * u
    fwd = target - centre
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, u)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    from ..cameras.pinhole import PinholeCamera

    w, h = image_size
    cam = PinholeView(PinholeCamera(f_px, f_px, w / 2.0, h / 2.0, dist, w, h), R, -R @ centre)
    W = cam.project(X)
    if noise_px > 0:
        W = W + rng.normal(scale=float(noise_px), size=W.shape)
    return W, cam


def orthographic_view(poses: Any, camera: PinholeView, *, noise_px: float = 0.0, seed: Any = None) -> np.ndarray:
    """The same static view without perspective: tracks (F, J, 2) of the orthographic projection
    along the camera's axis, scaled by f / (the mean depth of the subject) and centred like the
    pinhole view (the comparison the perspective benchmark rows make)."""
    X = np.asarray(poses, float)
    Xc = camera.to_camera(X)
    zbar = float(np.nanmean(Xc[..., 2]))
    K = camera.camera.K
    W = K[0, 0] * (Xc[..., :2] - np.nanmean(Xc[..., :2].reshape(-1, 2), 0)) / zbar + K[:2, 2]
    if noise_px > 0:
        W = W + np.random.default_rng(seed).normal(scale=float(noise_px), size=W.shape)
    return W


# ------------------------------------------------------------------------------ turned walks
def _yaw(theta: np.ndarray, up: str) -> np.ndarray:
    """(F, 3, 3) rotations by ``theta`` about the up axis."""
    u, h1, h2 = _axes(up)
    c, s = np.cos(theta)[:, None, None], np.sin(theta)[:, None, None]
    # R v = (v.u) u + cos (v_h) + sin (u x v_h)
    I = np.eye(3)
    uu = np.outer(u, u)
    ux = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    return uu + c * (I - uu) + s * ux


def bend_walk(poses: Any, heading: Any, *, up: str = "z") -> np.ndarray:
    """Real motion along a bent path: every frame of ``poses`` (F, J, 3) is turned rigidly about
    the vertical through its root by ``heading[k]`` (radians, (F,)), and the root's horizontal
    path is re-integrated from the original per-frame root displacements turned by the same angle.
    A straight walk with a heading that grows with the distance walked becomes a walk along a
    circle; nothing else of the motion changes (the limbs, the root height, the timing)."""
    X = np.asarray(poses, float)
    th = np.broadcast_to(np.asarray(heading, float), (len(X),))
    u = _axes(up)[0]
    Rz = _yaw(th, up)
    root = X[:, 0]
    rel = X - root[:, None]
    height = (root @ u)[:, None] * u
    step = np.diff(root - height, axis=0)  # horizontal root displacement per frame
    # the displacement between frames k and k+1 turned by the mean heading of the two frames
    mid = _yaw(0.5 * (th[1:] + th[:-1]), up)
    path = np.concatenate([(root[:1] - height[:1]), (root[:1] - height[:1]) + np.cumsum(np.einsum("fij,fj->fi", mid, step), 0)])
    return np.einsum("fij,fkj->fki", Rz, rel) + (path + height)[:, None]


def _walked(poses: np.ndarray, up: str) -> np.ndarray:
    """(F,) horizontal distance walked by the root up to each frame."""
    u = _axes(up)[0]
    root = poses[:, 0] - (poses[:, 0] @ u)[:, None] * u
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(root, axis=0), axis=-1))])


def turning_walk(poses: Any, *, turn_deg: float = 360.0, up: str = "z") -> np.ndarray:
    """A walk turned through ``turn_deg`` degrees (a full circle by default): the heading grows in
    proportion to the distance walked (:func:`bend_walk`), so a straight walk becomes an arc of
    constant curvature and the subject shows the camera every side."""
    X = np.asarray(poses, float)
    s = _walked(X, up)
    return bend_walk(X, np.deg2rad(turn_deg) * s / max(s[-1], 1e-12), up=up)


def out_and_back(poses: Any, *, turn_frames: float = 0.25, up: str = "z") -> np.ndarray:
    """A walk that goes one way for the first part, turns round (180 degrees, smoothly over the
    middle ``turn_frames`` fraction of the distance walked) and comes back: seen by a camera on the
    walking line it walks towards the camera and then away (or away, then towards)."""
    X = np.asarray(poses, float)
    s = _walked(X, up)
    a = s / max(s[-1], 1e-12)
    lo, hi = 0.5 - turn_frames / 2, 0.5 + turn_frames / 2
    r = np.clip((a - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return bend_walk(X, np.pi * (r - np.sin(2 * np.pi * r) / (2 * np.pi)), up=up)


def walking_direction(poses: Any, *, up: str = "z") -> float:
    """Azimuth (degrees about the up axis, from the first horizontal axis) of the root's net
    displacement over the sequence: place a camera at this azimuth to have the subject walk
    towards it (for :func:`out_and_back`, along the line of the outward leg)."""
    X = np.asarray(poses, float)
    u, h1, h2 = _axes(up)
    d = X[-1, 0] - X[0, 0]
    return float(np.rad2deg(np.arctan2(d @ h2, d @ h1)))
