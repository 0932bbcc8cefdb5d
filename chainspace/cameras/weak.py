"""Per-frame weak-perspective cameras: fit to bones, and projection.

A weak-perspective camera is the (2, 3) matrix ``P = s * R[:2]`` with ``R`` a rotation and ``s > 0``
the scale (image units per world unit). It is exactly the two constraints of Wandt et al. (2017,
Sec. 3.3): rows orthogonal, rows of equal norm. Bones are translation free, so fitting a camera to
bones (``W C ~ P B``) needs no image translation.

:func:`fit_cameras` solves, for every frame k at once,

    min_{s_k, R_k}  sum_l  w_kl * || w_kl_2d - s_k R_k[:2] b_kl ||^2

starting from the closed-form projection of the unconstrained affine least-squares camera onto the
constraint set (one batched SVD), followed by batched Gauss-Newton steps on (s, rotation) with a
Levenberg damping and a monotone acceptance test per frame, so the result is never worse than the
closed-form start.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..blocks import frame_blocks, join_blocks
from ..errors import TrackError

__all__ = ["fit_cameras", "fit_to_moments", "bone_moments", "per_frame_product", "project", "camera_scale", "complete_rotation", "rodrigues",
           "smooth_scales"]


def _rows(a: np.ndarray, dim: int, other: int | None, name: str) -> np.ndarray:
    """Return vectors as (..., L, dim) from (..., dim, L) or (..., L, dim)."""
    if a.shape[-1] == dim and (a.shape[-2] != dim or other is None or a.shape[-2] == other):
        return a
    if a.shape[-2] == dim:
        return np.swapaxes(a, -1, -2)
    raise TrackError(f"{name} has shape {a.shape}: expected (F, {dim}, L) or (F, L, {dim})")


def rodrigues(omega: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices exp([omega]x) for rotation vectors (..., 3)."""
    omega = np.asarray(omega, dtype=float)
    return np.moveaxis(_rodrigues_entries(np.moveaxis(omega, -1, 0)), (0, 1), (-2, -1))


def _rodrigues_entries(omega: np.ndarray) -> np.ndarray:
    """Rotations exp([omega]x) entries first, (3, 3, ...), for rotation vectors (3, ...)."""
    th2 = (omega * omega).sum(0)
    th = np.sqrt(th2)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    # I + a K + b K K, with K K = omega omega^T - |omega|^2 I (no stacked matrix product)
    R = b * (omega[:, None] * omega[None, :])
    diag = 1.0 - b * th2
    for i in range(3):
        R[i, i] += diag
    ax, ay, az = a * omega[0], a * omega[1], a * omega[2]
    R[0, 1] -= az
    R[1, 0] += az
    R[0, 2] += ay
    R[2, 0] -= ay
    R[1, 2] -= ax
    R[2, 1] += ax
    return R


def complete_rotation(Q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation whose first two rows are the orthonormal rows of Q (..., 2, 3)."""
    return np.concatenate([Q, np.cross(Q[..., 0, :], Q[..., 1, :])[..., None, :]], axis=-2)


def camera_scale(cameras: Any) -> np.ndarray:
    """(F,) scale of weak-perspective cameras: the mean row norm."""
    P = np.asarray(cameras, dtype=float)
    return np.linalg.norm(P, axis=-1).mean(axis=-1)


def fit_cameras(
    W_bones: Any,
    B: Any,
    weights: Any = None,
    *,
    n_iter: int = 5,
    fill: bool = True,
    return_rotation: bool = False,
    R0: Any = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best weak-perspective camera per frame mapping 3D bones ``B`` to observed 2D bones ``W_bones``.

    Parameters
    ----------
    W_bones
        (F, 2, L) or (F, L, 2) observed 2D bone vectors ``W C`` (image units). NaN entries get weight 0.
    B
        (F, 3, L), (F, L, 3) or a shared (L, 3) set of 3D bone vectors (world units).
    weights
        Optional (F, L) non-negative weights per bone (confidences).
    n_iter
        Gauss-Newton iterations after the closed-form start.
    fill
        Frames with fewer than two usable bones get the camera of the nearest usable frame (else NaN).
    return_rotation
        Also return the scales (F,) and full rotations (F, 3, 3).
    R0
        Optional (F, 3, 3) or (3, 3) rotations to start from (a warm start) instead of the closed form.

    Returns
    -------
    cameras (F, 2, 3) with orthogonal rows of equal norm ``s`` (and ``s``, ``R`` when asked).
    """
    W = np.asarray(W_bones, dtype=float)
    Bx = np.asarray(B, dtype=float)
    W = _rows(W, 2, None, "W_bones")
    if W.ndim != 3:
        raise TrackError(f"W_bones has shape {W.shape}: expected (F, 2, L) or (F, L, 2)")
    F, L = W.shape[:2]
    Bx = _rows(Bx, 3, L, "B")
    shared = Bx if Bx.ndim == 2 and np.isfinite(Bx).all() else None
    Bx = np.broadcast_to(Bx, (F, L, 3)) if Bx.ndim == 2 else Bx
    if Bx.shape != (F, L, 3):
        raise TrackError(f"B has shape {np.shape(B)}, which does not match W_bones {np.shape(W_bones)}")
    w = np.ones((F, L)) if weights is None else np.broadcast_to(np.asarray(weights, float), (F, L)).copy()
    # a sum of the coordinates is finite only when each of them is
    ok = (w > 0) & np.isfinite(W[..., 0] + W[..., 1]) & np.isfinite(Bx[..., 0] + Bx[..., 1] + Bx[..., 2])
    if not ok.all():
        w = np.where(ok, w, 0.0)
        W = np.where(ok[..., None], W, 0.0)
        Bx = Bx if shared is not None else np.where(ok[..., None], Bx, 0.0)

    # Every quantity below depends on the data only through these per-frame moments, so the
    # iterations cost O(F), not O(F L): G = B^T w B (3x3), H = W^T w B (2x3), c0 = sum w |W|^2.
    G, H, c0 = _data_moments(W, Bx, w) if shared is None else _shared_moments(W, shared, w)
    R0e = None if R0 is None else np.moveaxis(np.broadcast_to(np.asarray(R0, float), (F, 3, 3)), 0, -1).copy()
    s, R = fit_to_moments(G, H, c0, ok.sum(-1) >= 2, R0=R0e, n_iter=n_iter, fill=fill)
    R = np.ascontiguousarray(np.moveaxis(R, -1, 0))
    P = s[:, None, None] * R[:, :2]
    return (P, s, R) if return_rotation else P


def fit_to_moments(G: np.ndarray, H: np.ndarray, c0: np.ndarray, usable: np.ndarray, *, R0: Any = None,
                   n_iter: int = 5, fill: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The cameras of :func:`fit_cameras` from the frames' moments, matrices entries first (frames
    last): G = sum_l w b b^T (3, 3, F), H = sum_l w x b^T (2, 3, F), c0 = sum_l w |x|^2 (F,).
    ``usable`` (F,): the frames with two or more weighted bones (the others are filled as in
    :func:`fit_cameras`); R0 (3, 3, F) a warm start. Returns the scales s (F,) and rotations R
    (3, 3, F), entries first: a product of stacks of 3 x 3 matrices is then a few passes over
    F-vectors, several times faster than a stacked matmul."""
    F = len(c0)
    # the frames are independent: a block of frames at a time, whose temporaries stay in cache
    s, R = join_blocks([_fit_block(G[..., b], H[..., b], c0[b], None if R0 is None else R0[..., b], n_iter)
                        for b in frame_blocks(F, frames_last=True)])
    s = np.abs(s)
    if fill and not usable.all() and usable.any():
        idx = np.flatnonzero(usable)
        near = idx[np.clip(np.searchsorted(idx, np.arange(F)), 0, len(idx) - 1)]
        prev = idx[np.clip(np.searchsorted(idx, np.arange(F)) - 1, 0, len(idx) - 1)]
        near = np.where(np.abs(prev - np.arange(F)) <= np.abs(near - np.arange(F)), prev, near)
        s, R = s[near], R[..., near]
    elif not usable.all():
        s = np.where(usable, s, np.nan)
        R = np.where(usable, R, np.nan)
    return s, R


def _fit_block(G, H, c0, R0, n_iter):
    """:func:`fit_to_moments` on one block of frames, before the unusable frames are filled."""
    R = _closed_form_rotations(G, H) if R0 is None else np.asarray(R0, dtype=float)
    s, R, cost = _scale_and_cost(G, H, c0, R)
    lam = np.full(len(c0), 1e-6)
    for _ in range(n_iter):
        s, R, cost, lam = _gauss_newton_step(G, H, c0, s, R, cost, lam)
    return s, R


def bone_moments(W: np.ndarray, B: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The moments G = sum_l w b b^T (3, 3, F) and H = sum_l w x b^T (2, 3, F) of
    :func:`fit_to_moments` from frames-last arrays: 2D bones W (2, L, F), 3D bones B (3, L, F),
    weights w (L, F) (0 where a bone is unusable, with W 0 there). (c0 = sum_l w |x|^2 is
    ``(w * (W[0] ** 2 + W[1] ** 2)).sum(0)``.)"""
    wB = B * w
    G = np.empty((3, 3, B.shape[-1]))
    for i in range(3):
        for j in range(i, 3):
            G[i, j] = G[j, i] = np.einsum("lf,lf->f", wB[i], B[j])
    return G, np.einsum("ilf,jlf->ijf", W, wB)


def _orthonormal_rows(M: np.ndarray) -> np.ndarray:
    """The nearest matrices with orthonormal rows to M (2, 3, F), entries first: U V^T of the SVD
    M = U S V^T, in closed form: (M M^T)^(-1/2) M, where a 2 x 2 A = M M^T with r = sqrt(det A) has
    the square root (A + r I) / sqrt(tr A + 2 r) (a batched SVD of many 2 x 3 matrices is slow); the
    SVD where M is (nearly) of rank one."""
    a00, a01, a11 = (M[0] * M[0]).sum(0), (M[0] * M[1]).sum(0), (M[1] * M[1]).sum(0)
    det, tr = a00 * a11 - a01 * a01, a00 + a11
    ok = det > 1e-12 * tr**2
    r = np.sqrt(np.where(ok, det, 1.0))
    # (A + r I)^-1 = adj(A + r I) / det(A + r I), det(A + r I) = r (tr + 2 r)
    k = 1.0 / (r * np.sqrt(tr + 2.0 * r))
    Q = np.stack([((a11 + r) * M[0] - a01 * M[1]) * k, ((a00 + r) * M[1] - a01 * M[0]) * k])
    if not ok.all():
        U, _, Vt = np.linalg.svd(np.moveaxis(M[..., ~ok], -1, 0), full_matrices=False)
        Q[..., ~ok] = np.moveaxis(U @ Vt, 0, -1)
    return Q


def _closed_form_rotations(G: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Rotations (3, 3, F) from the affine camera M = H G^-1 projected onto orthonormal rows, entries
    first; G^-1 of the symmetric G (ridged by 1e-9 of its trace) from its cofactors."""
    ridge = 1e-9 * (G[0, 0] + G[1, 1] + G[2, 2]) + 1e-300
    g00, g11, g22 = G[0, 0] + ridge, G[1, 1] + ridge, G[2, 2] + ridge
    g01, g02, g12 = G[0, 1], G[0, 2], G[1, 2]
    c00, c01, c02 = g11 * g22 - g12 * g12, g02 * g12 - g01 * g22, g01 * g12 - g02 * g11
    c11, c12, c22 = g00 * g22 - g02 * g02, g01 * g02 - g00 * g12, g00 * g11 - g01 * g01
    det = g00 * c00 + g01 * c01 + g02 * c02
    det = np.where(det > 0, det, np.inf)  # a frame without data (det underflows): M = 0, the SVD's start
    inv = np.stack([np.stack([c00, c01, c02]), np.stack([c01, c11, c12]), np.stack([c02, c12, c22])]) / det
    Q = _orthonormal_rows(per_frame_product(H, inv))
    return np.concatenate([Q, np.cross(Q[0], Q[1], axis=0)[None]])


def _data_moments(W: np.ndarray, B: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """G = sum_l w b b^T (3, 3, F), H = sum_l w x b^T (2, 3, F) and c0 = sum_l w |x|^2 (F,) of 2D
    bones W (F, L, 2), 3D bones B (F, L, 3) and weights w (F, L)."""
    wB = w[..., None] * B
    G = np.swapaxes(wB, -1, -2) @ B  # a stacked matmul over L is the fastest way here
    H = np.swapaxes(W, -1, -2) @ wB
    c0 = np.einsum("fl,fli,fli->f", w, W, W)
    return np.ascontiguousarray(G.transpose(1, 2, 0)), np.ascontiguousarray(H.transpose(1, 2, 0)), c0


def _shared_moments(W: np.ndarray, B: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_data_moments` for one set of 3D bones B (L, 3) shared by every frame: G and H are then
    matrix products over the bones, (F, L) x (L, 9) and (2F, L) x (L, 3)."""
    F, L = w.shape
    G = w @ (B[:, :, None] * B[:, None, :]).reshape(L, 9)
    H = (np.swapaxes(W, 1, 2) * w[:, None, :]).reshape(2 * F, L) @ B
    c0 = (w * (W[..., 0] ** 2 + W[..., 1] ** 2)).sum(-1)
    return (np.ascontiguousarray(G.T.reshape(3, 3, F)), np.ascontiguousarray(H.reshape(F, 2, 3).transpose(1, 2, 0)), c0)


def per_frame_product(M: np.ndarray, X: np.ndarray, transpose: bool = False, out: np.ndarray | None = None
                      ) -> np.ndarray:
    """Per-frame products M_k X_k (or M_k^T X_k) of small matrices M (p, q, F) and arrays X (q, ...,
    F), both frames last (entries first): out[i] = sum_j M[i, j] X[j], sums of q products of
    F-vectors. One einsum: a broadcast product and sum was 1.4-1.6 times slower (its temporaries)."""
    return np.einsum("jif,j...f->i...f" if transpose else "ijf,j...f->i...f", M, X, out=out)


def _moments(G: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Moments in camera axes: Gy = R G R^T (3x3) and Hy = H R^T (2x3), entries first."""
    Rt = R.transpose(1, 0, 2)
    return per_frame_product(per_frame_product(R, G), Rt), per_frame_product(H, Rt)


def _scale_and_cost(G, H, c0, R):
    """Best scale for rotation R and the resulting cost, from the first two rows of R only."""
    R2 = R[:2]
    num = (H * R2).sum((0, 1))  # tr(H R2^T)
    den = (per_frame_product(R2, G) * R2).sum((0, 1))  # tr(R2 G R2^T)
    s = np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)
    # A negative scale is a rotation by pi about the view axis: fold it into R.
    flip = s < 0
    if flip.any():
        R = R.copy()
        R[:2, :, flip] *= -1.0
        s = np.abs(s)
    return s, R, c0 - s * np.abs(num)


def _gauss_newton_step(G, H, c0, s, R, cost, lam):
    """One damped Gauss-Newton step on (s, rotation vector), kept per frame only if it lowers the cost.

    The Jacobians of a predicted 2D bone (x, y) w.r.t. (ds, w1, w2, w3), for R <- exp([w]x) R, are
    linear in the camera-axes bone y: Jx = (y0, 0, s y2, -s y1), Jy = (y1, -s y2, 0, s y0), so the
    normal matrix sum_l w (Jx Jx^T + Jy Jy^T) and the gradient are written out in the moments
    Gy = sum w y y^T and Hy (no per-frame matrix products). Matrices entries first, (3, 3, F).
    """
    Gy, Hy = _moments(G, H, R)
    g00, g02 = Gy[0, 0], Gy[0, 2]
    g11, g12, g22 = Gy[1, 1], Gy[1, 2], Gy[2, 2]
    s2 = s * s
    # the normal matrix, entries (F,) (those at (0, 3) and (1, 2) are 0), Levenberg-damped
    diag = [g00 + g11, s2 * g22, s2 * g22, s2 * (g00 + g11)]
    ridge = 1e-12 * (diag[0] + diag[1] + diag[2] + diag[3] + 1e-300)
    N = [[a + lam * a + ridge if i == j else None for j, a in enumerate(diag)] for i in range(4)]
    N[1][0], N[2][0], N[3][0], N[2][1], N[3][1], N[3][2] = -s * g12, s * g02, 0.0, 0.0, -s2 * g02, -s2 * g12
    vx = Hy[0] - s * Gy[:, 0]  # sum_l w (observed x - predicted x) y, (3, F)
    vy = Hy[1] - s * Gy[:, 1]
    g = [vx[0] + vy[1], -s * vy[2], s * vx[2], s * (vy[0] - vx[1])]
    d = _solve_spd4(N, g)
    R_new = per_frame_product(_rodrigues_entries(d[1:]), R)
    s_new, R_new, c_new = _scale_and_cost(G, H, c0, R_new)
    better = c_new <= cost
    s = np.where(better, s_new, s)
    R = np.where(better, R_new, R)
    cost = np.where(better, c_new, cost)
    lam = np.where(better, lam * 0.3, lam * 10.0)
    return s, R, cost, lam


def _solve_spd4(N: list, b: list) -> np.ndarray:
    """(4, F) solutions of F symmetric positive definite 4 x 4 systems given entry by entry: N[i][j]
    (i >= j) and b[i] are (F,) arrays (or 0), by a Cholesky factorisation written out on them
    (several times faster than a batched np.linalg.solve of (F, 4, 4) systems)."""
    L = [[0.0] * 4 for _ in range(4)]
    for j in range(4):
        L[j][j] = np.sqrt(N[j][j] - sum(L[j][k] ** 2 for k in range(j)))
        for i in range(j + 1, 4):
            L[i][j] = (N[i][j] - sum(L[i][k] * L[j][k] for k in range(j))) / L[j][j]
    y: list = [0.0] * 4
    for i in range(4):
        y[i] = (b[i] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i]
    x: list = [0.0] * 4
    for i in (3, 2, 1, 0):
        x[i] = (y[i] - sum(L[k][i] * x[k] for k in range(i + 1, 4))) / L[i][i]
    return np.stack(x)


def project(poses: Any, cameras: Any, translations: Any = None) -> np.ndarray:
    """Tracks (F, J, 2) = poses (F, J, 3) @ cameras^T (F, 2, 3) + translations (F, 2)."""
    X = np.asarray(poses, dtype=float)
    P = np.asarray(cameras, dtype=float)
    if X.shape[-1] != 3 or P.shape[-2:] != (2, 3):
        raise TrackError(f"project needs poses (F, J, 3) and cameras (F, 2, 3), got {X.shape} and {P.shape}")
    out = X @ np.swapaxes(P, -1, -2)
    if translations is not None:
        out = out + np.asarray(translations, dtype=float)[..., None, :]
    return out


def smooth_scales(scales: Any, weights: Any = None, *, degree: int = 2, n_iter: int = 3) -> np.ndarray:
    """Slowly varying camera scales (F,): a robust polynomial fit in time to ``log(scales)``.

    Per-frame weak-perspective scales fitted to a deforming chain jitter by several percent (each
    frame's bones are foreshortened differently), while the camera distance changes slowly; the
    jitter feeds straight into the in-image part of every bone. The fit (``degree`` 2 by default,
    reweighted ``n_iter`` times with Cauchy weights) keeps slow zooms and drops the jitter.
    """
    s = np.asarray(scales, dtype=float)
    F = len(s)
    w = np.ones(F) if weights is None else np.asarray(weights, float).copy()
    ok = np.isfinite(s) & (s > 0) & (w > 0)
    if ok.sum() <= degree + 1:
        return np.full(F, np.median(s[ok]) if ok.any() else 1.0)
    t = np.linspace(-1.0, 1.0, F)
    V = np.vander(t, degree + 1)
    y = np.log(np.where(ok, s, 1.0))
    w = np.where(ok, w, 0.0)
    for _ in range(n_iter):
        coef = np.linalg.lstsq(V * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0]
        r = y - V @ coef
        mad = 1.4826 * np.median(np.abs(r[ok])) + 1e-12
        w = np.where(ok, 1.0 / (1.0 + (r / (2.0 * mad)) ** 2), 0.0)
    return np.exp(V @ coef)
