"""Synthetic monocular views of 3D motion: random low-motion camera paths, projection, pixel noise.

This reproduces the protocol of Wandt et al. (2017, Sec. 4.1): a weak-perspective camera orbits the
subject about the vertical axis, starting at a random azimuth, sweeping a small total angle over the
sequence ("low camera motion"), at a random elevation. A camera is a (2, 3) matrix ``s * R[:2]``
with ``R`` a rotation whose rows are the image right, image down and viewing directions (image y
points down, as in pixel coordinates) and ``s`` the scale in image units (px) per metre.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import TrackError

__all__ = ["orbit_cameras", "observe", "scale_for_span", "look_rotation", "swing_motion"]

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
