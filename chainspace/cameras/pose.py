"""Where a pinhole camera stands, from a fitted weak-perspective camera.

A weak-perspective camera ``u = s R[:2] x + t2d`` is the pinhole camera ``u = f (R x + t)_xy / Z + c``
linearised about a point ``x0`` at depth ``Z0 = (R x0 + t)_z``: matching the two gives ``s = f / Z0`` and
``t2d = f t_xy / Z0 + c``. With the intrinsics known, :func:`pose_from_weak` inverts this for the pose
``(R, t)`` (``x_cam = R x + t``), which places the camera (its centre ``-R^T t``) in the scene.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import CameraError
from .weak import complete_rotation

__all__ = ["pose_from_weak"]


def pose_from_weak(P: Any, t2d: Any, camera: Any, centre: Any) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole pose ``(R (..., 3, 3), t (..., 3))`` matching weak-perspective cameras, one per
    leading index (a frame), or one camera without a leading axis.

    Parameters
    ----------
    P : (..., 2, 3) array-like
        Weak-perspective cameras ``s R[:2]``, pixels per scene unit.
    t2d : (..., 2) array-like
        Their image translations, pixels.
    camera : PinholeCamera or None
        The intrinsics; the mean focal length ``(fx + fy) / 2`` is taken for ``f``. None: the
        tracks are the camera's rays (normalised image coordinates x/z, y/z: ``f = 1``, ``c = 0``).
    centre : (..., 3) array-like
        The point each weak camera was fitted about (the subject's middle), scene units.

    Returns
    -------
    R, t
        ``x_cam = R x + t`` in scene units (metres when the scene is); the centre's depth is
        ``f / s``.
    """
    P = np.asarray(P, dtype=float)
    t2d = np.asarray(t2d, dtype=float)
    centre = np.asarray(centre, dtype=float)
    if P.shape[-2:] != (2, 3) or not np.all(np.isfinite(P)) or not np.all(np.isfinite(t2d)):
        raise CameraError(f"a weak-perspective camera must be a finite (2, 3) matrix, not shape {P.shape}")
    if t2d.shape != P.shape[:-2] + (2,) or centre.shape != P.shape[:-2] + (3,):
        raise CameraError(f"weak cameras {P.shape}, translations {t2d.shape} and centres {centre.shape} do not "
                          "match: expected (..., 2, 3), (..., 2), (..., 3)")
    s = np.linalg.norm(P, axis=-1).mean(axis=-1)
    if not np.all(s > 0):
        raise CameraError("the weak-perspective camera has zero scale")
    R = complete_rotation(P / np.linalg.norm(P, axis=-1, keepdims=True))
    u, _, vt = np.linalg.svd(R)  # rows orthonormal up to the fit's tolerance; make R exactly a rotation
    R = u @ vt
    f, c = (1.0, np.zeros(2)) if camera is None else (0.5 * (camera.fx + camera.fy), np.array([camera.cx, camera.cy]))
    t = np.concatenate([(t2d - c) / s[..., None],
                        (f / s - np.einsum("...i,...i->...", R[..., 2, :], centre))[..., None]], axis=-1)
    return R, t
