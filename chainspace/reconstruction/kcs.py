"""The Kinematic Chain Space factorization: Algorithm 1 of Wandt, Ackermann and Rosenhahn (2017).

Symbols (per frame k, chain matrices from :class:`~chainspace.chain.KinematicChain`):

* ``W`` observed 2D tracks (2 x J per frame), ``C`` (J x L) maps joints to links (bones ``B = X C``),
  ``D`` (n_bones x J) maps bones back to joints (``X = B D``, root at the origin).
* ``X0`` the initial pose (3 x J), ``B0 = X0 C`` its bones.
* ``P_k = s_k R_k[:2]`` the weak-perspective camera of frame k (rows orthogonal, equal norms).
* ``Q`` (3K x J) the pose basis: the first 3K right singular vectors of ``W - P X0`` (translation
  removed per frame); ``S = Q C`` (3K x L) the same basis in the KCS.
* ``A_k`` (3 x 3K) the transformation of frame k; ``A`` stacks them to (3F x 3K). The bones are
  ``B_k = A_k S + B0``.

The algorithm starts from ``A = 0`` and alternates (a) the per-frame cameras that best map ``B_k`` to
``W_k C`` (:func:`chainspace.cameras.weak.fit_cameras`) and (b) ``min ||A||_*  s.t.  W C = P (A S + B0)``.
Step (b) is solved in its penalty form ``min tau ||A||_* + 1/2 sum_k ||(W_k C - P_k (A_k S + B0)) w_k||^2``
by accelerated proximal gradient (FISTA; the proximal map of the nuclear norm is singular value
thresholding, SVT). The penalty weight follows a continuation schedule: in the first pass ``tau``
falls geometrically from ``tau_range[0]`` to ``tau_range[1]`` times the spectral norm of the first
gradient (1e-1 to 1e-4), so that the equality holds at the end as far as the data allow; later
passes, warm-started from the previous ``A``, stay at the small ``tau``. The singular values of the
(3F x 3K) matrix ``A`` come from its 3K x 3K Gram matrix, so an iteration costs O(F K L). The
steps run in camera axes, on ``R_k A_k`` (a block-diagonal rotation of the stacked ``A``, which
leaves its singular values alone), where ``P_k = s_k [I 0]``; with one weight per frame also in the
eigenbasis of ``S S^T``, where a descent step is a per-frame, per-column factor. The
camera step starts from the previous rotations (one Gauss-Newton step per pass: more did not change
the result).

Missing points (NaN) and confidences enter as weights on the bones of the data term: a bone's
weight is the smaller confidence of its two joints, 0 when either is missing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cameras.weak import fit_cameras

__all__ = ["kcs_factorize", "KCSResult", "bone_observations", "fit_translations", "reprojection_rms",
           "reprojection_with_translations"]


@dataclass
class KCSResult:
    """Output of :func:`kcs_factorize`. Poses are root-relative (F, J, 3) in the units of ``X0``."""

    poses: np.ndarray
    cameras: np.ndarray
    scales: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    A: np.ndarray
    S: np.ndarray
    n_iter: int
    converged: bool
    history: dict[str, list[float]] = field(default_factory=dict)


def bone_observations(chain: Any, tracks: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2D links ``W C`` as (F, L, 2) with NaN replaced by 0, and their weights (F, L)."""
    C = chain.C
    seen = np.isfinite(tracks).all(-1)
    w = np.where(seen, weights, 0.0)
    Wz = np.where(seen[..., None], tracks, 0.0)
    Wb = C.T @ Wz
    parent = np.argmin(C, axis=0)
    child = np.argmax(C, axis=0)
    wb = np.minimum(w[:, parent], w[:, child])
    return np.where(wb[..., None] > 0, Wb, 0.0), wb


def fit_translations(tracks: np.ndarray, weights: np.ndarray, poses: np.ndarray, cameras: np.ndarray) -> np.ndarray:
    """(F, 2) weighted least-squares image translations t_k with tracks ~= poses @ P^T + t."""
    pred = poses @ np.swapaxes(cameras, -1, -2)
    seen = np.isfinite(tracks).all(-1)
    w = np.where(seen, weights, 0.0)
    diff = np.where(seen[..., None], tracks - pred, 0.0)
    n = w.sum(-1, keepdims=True)
    return (w[..., None] * diff).sum(1) / np.where(n > 0, n, 1.0)


def reprojection_rms(tracks, weights, poses, cameras, translations) -> float:
    """Weighted RMS distance (image units) between tracks and reprojected poses."""
    pred = poses @ np.swapaxes(cameras, -1, -2) + translations[:, None, :]
    seen = np.isfinite(tracks).all(-1)
    w = np.where(seen, weights, 0.0)
    d2 = np.where(seen, ((np.where(seen[..., None], tracks, 0.0) - pred) ** 2).sum(-1), 0.0)
    return float(np.sqrt((w * d2).sum() / max(w.sum(), 1e-300)))


def reprojection_with_translations(Wt: np.ndarray, weights: np.ndarray, Xt: np.ndarray,
                                   P: np.ndarray) -> tuple[float, np.ndarray]:
    """Weighted reprojection RMS (image units) of poses Xt (F, 3, J) under cameras P (F, 2, 3) with
    the best translation per frame, and those translations (F, 2). Tracks Wt (F, 2, J) with 0
    where unseen and weights (F, J) 0 there: the (F, 2, J) layout keeps it cheap."""
    d = Wt - _PA(P, Xt)
    t = (d * weights[:, None, :]).sum(-1) / np.maximum(weights.sum(-1), 1e-300)[:, None]
    r2 = (weights[:, None, :] * (d - t[..., None]) ** 2).sum()
    return float(np.sqrt(r2 / max(weights.sum(), 1e-300))), t


def _pose_basis(tracks, weights, P, X0, n_basis):
    """Q (3K x J): leading right singular vectors of W - P X0, each frame's translation removed."""
    seen = np.isfinite(tracks).all(-1)
    w = np.where(seen, weights, 0.0)
    What = np.where(seen[..., None], tracks - X0 @ np.swapaxes(P, -1, -2), 0.0)  # (F, J, 2)
    n = w.sum(-1, keepdims=True)[..., None]
    mean = (w[..., None] * What).sum(1, keepdims=True) / np.where(n > 0, n, 1.0)
    What = np.where(seen[..., None], What - mean, 0.0) * np.sqrt(w)[..., None]
    M = np.swapaxes(What, 1, 2).reshape(-1, What.shape[1])  # (2F, J)
    evals, evecs = np.linalg.eigh(M.T @ M)
    k = min(n_basis, M.shape[1])
    return evecs[:, ::-1][:, :k].T.copy()


def _svt(A: np.ndarray, tau: float, out: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Singular value thresholding of the stacked (3F x 3K) matrix A given as (F, 3, 3K).

    The right singular vectors V and values come from the small Gram matrix, and the result is
    A V diag(gain) V^T = A N: one product with an (3K x 3K) matrix, or two thin ones through
    the r kept directions when r < 3K / 2 (the thresholded rank is often low). ``out``: an array
    like A to write the result to."""
    M = A.reshape(-1, A.shape[-1])
    evals, V = np.linalg.eigh(M.T @ M)
    sig = np.sqrt(np.maximum(evals, 0.0))
    shrunk = np.maximum(sig - tau, 0.0)
    keep = shrunk > 0
    Vk = V[:, keep]
    Vg = Vk * (shrunk[keep] / sig[keep])
    res = np.empty(A.shape) if out is None else out
    if 2 * Vk.shape[1] < M.shape[1]:
        np.matmul(M @ Vg, Vk.T, out=res.reshape(M.shape))
    else:
        np.matmul(M, Vg @ Vk.T, out=res.reshape(M.shape))
    return res, float(shrunk.sum())


def _PA(P: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Per-frame products P_k A_k, (F, r, 3) x (F, 3, m) -> (F, r, m)."""
    return np.matmul(P, A)


def _PtG(P: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Per-frame products P_k^T G_k, (F, 2, 3) x (F, 2, m) -> (F, 3, m)."""
    return np.matmul(np.swapaxes(P, -1, -2), G)


def _solve_A(A, Rot, s, S, R, wb, taus):
    """FISTA on tau ||A||_* + 1/2 sum_k || (P_k A_k S - R_k) sqrt(w_k) ||^2, one step per tau in taus,
    with P_k = s_k Rot_k[:2].

    The steps run in camera axes, on Rot_k A_k: stacking the frames' rotations gives a block-diagonal
    orthogonal matrix, so the nuclear norm, and the SVT with it, are unchanged, while P_k becomes
    s_k [I 0]: the data term acts on the first two rows only and the gradient needs no per-frame
    3 x 3 products. The arrays are rows-first (3, F, 3K), so those two rows are one contiguous block."""
    F, m = A.shape[0], A.shape[-1]
    # Lipschitz constant of the gradient: max_k s_k^2 * lambda_max(S diag(w_k) S^T) <= max_k s_k^2 * ||S||^2 max w
    lip = float((s**2 * wb.max(-1)).max() * np.linalg.norm(S, 2) ** 2)
    if lip <= 0:
        return A
    step = 1.0 / lip
    St = np.ascontiguousarray(S.T)
    Rc = np.ascontiguousarray(np.swapaxes(R, 0, 1))  # (2, F, L)
    wk = wb[:, 0]
    uniform = bool((wb == wk[:, None]).all())
    # One weight per frame (every bone seen, equal confidences): in the eigenbasis U of S S^T (A -> A U,
    # which the SVT commutes with) S S^T = U diag(lam) U^T is diagonal, and the descent step is a
    # product with a per-frame, per-column factor.
    lam, U = np.linalg.eigh(S @ St) if uniform else (None, np.eye(m))
    A_prev = (np.swapaxes(Rot @ A, 0, 1).reshape(3 * F, m) @ U).reshape(3, F, m)
    if uniform:
        fac = 1.0 - (step * wk * s**2)[:, None] * lam  # (F, 3K)
        c = (Rc.reshape(2 * F, -1) @ (St @ U)).reshape(2, F, m) * (step * wk * s)[:, None]

        def descent(Y):  # Y - step * gradient(Y) in place, the third row unchanged
            Y[:2] *= fac
            Y[:2] += c
            return Y
    else:
        sw = s[:, None] * wb  # (F, L)

        def descent(Y):
            res = (Y[:2].reshape(2 * F, m) @ S).reshape(2, F, -1) * s[:, None] - Rc  # (2, F, L)
            res *= sw
            Y[:2] -= step * (res.reshape(2 * F, -1) @ St).reshape(2, F, m)
            return Y
    # three buffers in turn, no array allocated per step: Y (descended in place), A_prev, spare
    Y, spare, t = A_prev.copy(), np.empty_like(A_prev), 1.0
    for tau in taus:
        A_new, _ = _svt(descent(Y), step * tau, out=spare)
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        # Y = A_new + beta (A_new - A_prev), into the descended Y's buffer
        beta = (t - 1.0) / t_new
        np.subtract(A_new, A_prev, out=Y)
        Y *= beta
        Y += A_new
        spare, A_prev, t = A_prev, A_new, t_new
    del Y, spare  # the buffers go before the result is turned back to world axes (peak memory)
    return np.swapaxes(Rot, 1, 2) @ np.swapaxes((A_prev.reshape(3 * F, m) @ U.T).reshape(3, F, m), 0, 1)


def kcs_factorize(
    tracks: np.ndarray,
    weights: np.ndarray,
    chain: Any,
    X0: np.ndarray,
    *,
    n_basis: int | None = None,
    max_iter: int = 10,
    tol: float = 1e-3,
    svt_steps: int = 20,
    tau_range: tuple[float, float] = (1e-1, 1e-4),
    truth: np.ndarray | None = None,
    error_fn: Any = None,
) -> KCSResult:
    """Algorithm 1 on tracks (F, J, 2) with weights (F, J) in [0, 1] (0 where NaN).

    ``n_basis`` is 3K, the rank of the pose basis (default: the number of joints minus one, capped
    at 15). ``tau_range`` gives the SVT threshold schedule relative to the spectral norm of the first
    gradient. Convergence: the reprojection RMS changes by less than ``tol`` times that of the
    initial pose, or the bones move by less than ``tol`` times their RMS length.
    History keys: ``reprojection`` (image units, one entry per iteration, entry 0 = initial pose) and,
    with ``truth`` and ``error_fn``, ``error_3d``.
    """
    F, J = tracks.shape[:2]
    C = chain.C
    weights = np.where(np.isfinite(tracks).all(-1), weights, 0.0)
    B0 = (C.T @ X0).T  # (3, L)
    Wb, wb = bone_observations(chain, tracks, weights)
    Wb_cols = np.swapaxes(Wb, 1, 2)  # (F, 2, L)
    P, s, Rot = fit_cameras(Wb, B0.T, wb, return_rotation=True)
    k3 = int(n_basis) if n_basis else min(J - 1, 15)
    Q = _pose_basis(tracks, weights, P, X0, k3)
    S = Q @ C  # (3K, L)
    A = np.zeros((F, 3, Q.shape[0]))
    hist: dict[str, list[float]] = {"reprojection": []}

    nb = chain.n_bones
    Dm = np.ascontiguousarray(chain.D)
    Wt = np.swapaxes(np.where(np.isfinite(tracks), tracks, 0.0), 1, 2)  # (F, 2, J)

    def record(B, P):
        # Reprojection RMS with the best translation per frame, all in (F, 2, J) layout (cheap).
        Xt = (B[:, :, :nb].reshape(-1, nb) @ Dm).reshape(F, 3, -1)  # (F, 3, J)
        rms, t = reprojection_with_translations(Wt, weights, Xt, P)
        hist["reprojection"].append(rms)
        X = np.swapaxes(Xt, 1, 2)
        if truth is not None and error_fn is not None:
            hist.setdefault("error_3d", []).append(float(error_fn(X, truth)))
        return X, t

    X, t = record(np.broadcast_to(B0, (F,) + B0.shape), P)
    # The threshold scale: spectral norm of the gradient at A = 0 (where every singular value would
    # be thresholded away if tau were larger).
    R = Wb_cols - _PA(P, B0)
    g0 = _PtG(P, ((R * wb[:, None, :]).reshape(2 * F, -1) @ S.T).reshape(F, 2, -1))
    g0n = float(np.sqrt(max(np.linalg.eigvalsh(g0.reshape(-1, g0.shape[-1]).T @ g0.reshape(-1, g0.shape[-1]))[-1], 0)))
    tau_hi, tau_lo = tau_range[0] * g0n, tau_range[1] * g0n
    converged, it = False, 0
    B_prev = np.broadcast_to(B0, (F,) + B0.shape)
    b_rms = float(np.sqrt((B0**2).sum(0).mean()))
    for it in range(1, max_iter + 1):
        R = Wb_cols - _PA(P, B0)
        # Continuation: the first pass lowers tau from tau_hi to tau_lo; later passes, warm-started
        # from the previous A, stay at tau_lo.
        taus = np.geomspace(tau_hi, tau_lo, svt_steps) if it == 1 else np.full(max(svt_steps // 4, 1), tau_lo)
        A = _solve_A(A, Rot, s, S, R, wb, taus)
        B = (A.reshape(-1, A.shape[-1]) @ S).reshape(F, 3, -1) + B0
        P, s, Rot = fit_cameras(Wb, np.swapaxes(B, 1, 2), wb, return_rotation=True, R0=Rot, n_iter=1)
        X, t = record(B, P)
        r0, r1 = hist["reprojection"][-2], hist["reprojection"][-1]
        # Converged when the reprojection RMS changes by less than tol times the initial pose's
        # (at zero noise the RMS itself tends to 0) or the bones move by less than tol times their
        # RMS length (the paper: "only deform the 3D reconstruction less than 1 mm").
        moved = float(np.sqrt(((B - B_prev) ** 2).sum(1).mean()))
        B_prev = B
        if it >= 2 and (abs(r0 - r1) <= tol * max(hist["reprojection"][0], 1e-12) or moved <= tol * b_rms):
            converged = True
            break
    return KCSResult(X, P, s, Rot, t, A, S, it, converged, hist)
