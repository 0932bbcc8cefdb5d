"""Error measures for 3D reconstructions: MPJPE, the paper's "3D error", bone-length statistics.

All functions are vectorised over frames. Poses are (F, J, 3) (a single (J, 3) pose is accepted too);
distances come back in the units of the poses (metres for chainspace data). Joints that are NaN in
either array are left out of the alignment and of the means.

The "3D error" of Wandt et al. (2017) is the 3D positioning error (3DPE) of Simo-Serra et al.: each
frame of the reconstruction is rigidly aligned to the truth (Procrustes), the mean joint distance is
taken, and the result is averaged over frames.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import TrackError

__all__ = ["mpjpe", "procrustes_align", "error_3d", "per_frame_error", "bone_length_stats"]


def _pair(pred: Any, truth: Any) -> tuple[np.ndarray, np.ndarray]:
    P = np.asarray(pred, dtype=float)
    T = np.asarray(truth, dtype=float)
    if P.shape != T.shape or P.ndim < 2 or P.shape[-1] != 3:
        raise TrackError(f"pred {P.shape} and truth {T.shape} must both be (F, J, 3) or (J, 3)")
    return P, T


def _joint_mean(d: np.ndarray) -> np.ndarray:
    """Mean over joints of per-joint distances (..., J), ignoring NaN (all-NaN frames give NaN)."""
    ok = np.isfinite(d)
    n = ok.sum(axis=-1)
    s = np.where(ok, d, 0.0).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def mpjpe(pred: Any, truth: Any) -> float:
    """Mean per-joint position error, without any alignment (units of the poses)."""
    P, T = _pair(pred, truth)
    return float(np.nanmean(_joint_mean(np.linalg.norm(P - T, axis=-1))))


def procrustes_align(pred: Any, truth: Any, *, scale: bool = False, reflection: bool = False) -> np.ndarray:
    """Align every frame of ``pred`` to ``truth`` (Kabsch/Umeyama, one batched SVD over frames).

    Each frame gets its own rotation and translation (and uniform scale when ``scale``; an improper
    rotation when ``reflection``) minimising the summed squared joint distances. Returns the aligned
    prediction, same shape as ``pred``. NaN joints do not take part and stay NaN.
    """
    P, T = _pair(pred, truth)
    single = P.ndim == 2
    if single:
        P, T = P[None], T[None]
    ok = (np.isfinite(P).all(-1) & np.isfinite(T).all(-1))[..., None]  # (F, J, 1)
    n = np.maximum(ok.sum(axis=-2, keepdims=True), 1)
    P0, T0 = np.where(ok, P, 0.0), np.where(ok, T, 0.0)
    mp, mt = P0.sum(-2, keepdims=True) / n, T0.sum(-2, keepdims=True) / n
    Pc, Tc = np.where(ok, P0 - mp, 0.0), np.where(ok, T0 - mt, 0.0)
    M = np.swapaxes(Pc, -1, -2) @ Tc  # (F, 3, 3) cross-covariance
    U, S, Vt = np.linalg.svd(M)
    if not reflection:
        # Flip the weakest axis when the best orthogonal map is a reflection (Umeyama).
        d = np.sign(np.linalg.det(U @ Vt))
        d[d == 0] = 1.0
        U = U.copy()
        U[..., :, 2] *= d[..., None]
        S = S.copy()
        S[..., 2] *= d
    R = U @ Vt  # pred row-vectors map as x @ R
    if scale:
        var = (Pc**2).sum(axis=(-1, -2))
        c = np.where(var > 0, S.sum(-1) / np.where(var > 0, var, 1.0), 1.0)[..., None, None]
    else:
        c = 1.0
    out = c * (P - mp) @ R + mt
    return out[0] if single else out


def per_frame_error(pred: Any, truth: Any, *, scale: bool = False, reflection: bool = False) -> np.ndarray:
    """(F,) mean joint distance per frame after per-frame Procrustes alignment."""
    P, T = _pair(pred, truth)
    A = procrustes_align(P, T, scale=scale, reflection=reflection)
    return np.atleast_1d(_joint_mean(np.linalg.norm(A - T, axis=-1)))


def error_3d(pred: Any, truth: Any, *, scale: bool = False, reflection: bool = False) -> float:
    """The paper's 3D error: per-frame rigid alignment, mean joint distance, averaged over frames.

    ``scale=True`` allows a similarity transform per frame; ``reflection=True`` allows mirror images
    (monocular views cannot tell a pose from its mirror through the image plane). Units of the poses.
    """
    return float(np.nanmean(per_frame_error(pred, truth, scale=scale, reflection=reflection)))


def bone_length_stats(chain: Any, poses: Any) -> dict[str, np.ndarray]:
    """Per-link length statistics over frames: ``mean``, ``std`` (units of the poses) and ``cv``
    (std / mean, unitless), each (L,) in the order of ``chain.links``."""
    lengths = chain.bone_lengths(poses)
    lengths = lengths.reshape(-1, lengths.shape[-1])
    mean = np.nanmean(lengths, axis=0)
    std = np.nanstd(lengths, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cv = np.where(mean > 0, std / mean, np.nan)
    return {"mean": mean, "std": std, "cv": cv}
