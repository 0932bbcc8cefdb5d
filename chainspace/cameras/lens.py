"""A minimal pinhole camera with OpenCV's lens distortion (k1, k2, p1, p2, k3), for the robot fit and
the synthetic robot footage until :class:`chainspace.cameras.pinhole.PinholeCamera` (branch
``cameras``) replaces it. Same duck type the fit needs: ``K`` (3, 3) and ``undistort(pixels)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import DescriptionError


def _distort(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Normalised image points (..., 2) through OpenCV's distortion model."""
    k1, k2, p1, p2, k3 = dist
    x, y = xn[..., 0], xn[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                     y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], -1)


def _undistort(xd: np.ndarray, dist: np.ndarray, iters: int = 30) -> np.ndarray:
    """Inverse of :func:`_distort` by fixed-point iteration followed by Newton steps."""
    xn = xd.copy()
    for _ in range(iters):
        err = _distort(xn, dist) - xd
        h = 1e-7
        # numerical 2x2 Jacobian per point
        jx = (_distort(xn + [h, 0.0], dist) - _distort(xn, dist)) / h
        jy = (_distort(xn + [0.0, h], dist) - _distort(xn, dist)) / h
        det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
        det = np.where(np.abs(det) > 1e-12, det, 1e-12)
        dx = (jy[..., 1] * err[..., 0] - jy[..., 0] * err[..., 1]) / det
        dy = (-jx[..., 1] * err[..., 0] + jx[..., 0] * err[..., 1]) / det
        xn = xn - np.stack([dx, dy], -1)
        if np.nanmax(np.abs(err), initial=0.0) < 1e-12:
            break
    return xn


@dataclass
class Intrinsics:
    """K (3, 3) and distortion (k1, k2, p1, p2, k3) (zeros: none)."""

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def __post_init__(self):
        self.K = np.asarray(self.K, float)
        d = np.zeros(5)
        given = np.asarray(self.dist if self.dist is not None else [], float).reshape(-1)
        d[: len(given)] = given[:5]
        self.dist = d

    def project(self, y: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) -> pixels (..., 2)."""
        xn = y[..., :2] / y[..., 2:]
        if self.dist.any():
            xn = _distort(xn, self.dist)
        return xn @ self.K[:2, :2].T + self.K[:2, 2]

    def undistort(self, pixels: Any) -> np.ndarray:
        """Pixels (..., 2) as an ideal pinhole camera with the same K would see them (NaN kept)."""
        px = np.asarray(pixels, float)
        if not self.dist.any():
            return px.copy()
        xd = np.linalg.solve(self.K[:2, :2], (px - self.K[:2, 2]).reshape(-1, 2).T).T.reshape(px.shape)
        return _undistort(xd, self.dist) @ self.K[:2, :2].T + self.K[:2, 2]


def as_intrinsics(camera: Any) -> Any:
    """A camera object with ``K`` (kept as is when it has ``undistort``) or a 3x3 matrix -> an object
    with ``K`` and ``undistort``."""
    if hasattr(camera, "K") and hasattr(camera, "undistort"):
        return camera
    K = np.asarray(getattr(camera, "K", camera), float)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DescriptionError(f"intrinsics must be a camera with K and undistort, or a 3x3 matrix with positive "
                               f"focal lengths, not {camera!r}")
    return Intrinsics(K, getattr(camera, "dist", None))
