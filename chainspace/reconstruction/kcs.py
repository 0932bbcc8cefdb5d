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

from ..blocks import frame_blocks, join_blocks
from ..cameras.weak import bone_moments, fit_cameras, fit_to_moments, per_frame_product

__all__ = ["kcs_factorize", "KCSResult", "bone_observations", "fit_translations", "reprojection_rms",
           "reprojection_with_translations", "where_seen", "seen_points", "complex_points"]


def seen_points(points: Any) -> np.ndarray:
    """(...) True where both coordinates of points (..., 2) are finite: ``np.isfinite(points).all(-1)``,
    several times faster (the two coordinates tested together, as one complex number)."""
    p = np.asarray(points, dtype=float)
    if not p.flags.c_contiguous:
        return np.isfinite(p).all(-1)
    return np.isfinite(p.view(np.complex128)[..., 0])


def where_seen(points: Any, seen: np.ndarray, fill: float = 0.0) -> np.ndarray:
    """Points (..., 2) where ``seen`` (...) is true and ``fill`` elsewhere: ``np.where(seen[..., None],
    points, fill)``, 3-4 times faster. numpy runs that masked selection as an inner loop of two values
    per point; here each point's two coordinates are selected together, as one complex number."""
    return complex_points(points, seen, complex(fill, fill)).view(float).reshape(np.shape(points))


def complex_points(points: Any, seen: np.ndarray, fill: complex = 0j) -> np.ndarray:
    """Points (..., 2) as complex numbers x + iy (...) where ``seen`` (...) is true, ``fill`` elsewhere:
    sums and means over points are then one pass, not one per coordinate."""
    p = np.ascontiguousarray(points, dtype=float)
    return np.where(seen, p.view(np.complex128)[..., 0], fill)


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
    seen = seen_points(tracks)
    w = np.where(seen, weights, 0.0)
    Wb = C.T @ where_seen(tracks, seen)
    parent = np.argmin(C, axis=0)
    child = np.argmax(C, axis=0)
    wb = np.minimum(w[:, parent], w[:, child])
    return where_seen(Wb, wb > 0), wb


def fit_translations(tracks: np.ndarray, weights: np.ndarray, poses: np.ndarray, cameras: np.ndarray) -> np.ndarray:
    """(F, 2) weighted least-squares image translations t_k with tracks ~= poses @ P^T + t."""
    pred = poses @ np.swapaxes(cameras, -1, -2)
    seen = seen_points(tracks)
    w = np.where(seen, weights, 0.0)
    diff = where_seen(tracks - pred, seen)
    n = w.sum(-1, keepdims=True)
    return (w[..., None] * diff).sum(1) / np.where(n > 0, n, 1.0)


def reprojection_rms(tracks, weights, poses, cameras, translations) -> float:
    """Weighted RMS distance (image units) between tracks and reprojected poses."""
    pred = poses @ np.swapaxes(cameras, -1, -2) + translations[:, None, :]
    seen = seen_points(tracks)
    w = np.where(seen, weights, 0.0)
    d2 = np.where(seen, ((where_seen(tracks, seen) - pred) ** 2).sum(-1), 0.0)
    return float(np.sqrt((w * d2).sum() / max(w.sum(), 1e-300)))


def reprojection_with_translations(Wt: np.ndarray, weights: np.ndarray, Xt: np.ndarray,
                                   P: np.ndarray) -> tuple[float, np.ndarray]:
    """Weighted reprojection RMS (image units) of poses Xt (3, J, F) under cameras P (2, 3, F) with
    the best translation per frame, and those translations (F, 2). Tracks Wt (2, J, F) with 0
    where unseen and weights (J, F) 0 there. Frames last, a block of frames at a time: every
    per-frame product is then a pass over F-vectors that stay in cache."""
    t, r2 = np.empty((Wt.shape[-1], 2)), 0.0
    for b in frame_blocks(Wt.shape[-1], frames_last=True):
        w = weights[:, b]
        d = Wt[..., b] - per_frame_product(P[..., b], Xt[..., b])
        tb = np.einsum("cjf,jf->cf", d, w) / np.maximum(w.sum(0), 1e-300)
        d -= tb[:, None]
        r2 += float(np.einsum("cjf,cjf,jf->", d, d, w))  # weighted sums as einsums: 6 times faster
        t[b] = tb.T
    return float(np.sqrt(r2 / max(weights.sum(), 1e-300))), t


def _pose_basis(tracks, weights, P, X0, n_basis):
    """Q (3K x J): leading right singular vectors of W - P X0, each frame's translation removed.

    A point (x, y) is held as the complex number x + iy, so that the rows x and y of a frame are one
    row z, and the Gram matrix of the 2F x J matrix is Re(z^H z)."""
    seen = seen_points(tracks)
    w = np.where(seen, weights, 0.0)
    z = complex_points(tracks - X0 @ np.swapaxes(P, -1, -2), seen)  # (F, J)
    n = w.sum(-1)
    mean = (w * z).sum(1) / np.where(n > 0, n, 1.0)
    z = np.where(seen, z - mean[:, None], 0.0) * np.sqrt(w)
    evals, evecs = np.linalg.eigh((z.conj().T @ z).real)
    k = min(n_basis, z.shape[1])
    return evecs[:, ::-1][:, :k].T.copy()


def _shrinkage(gram: np.ndarray, tau: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Singular value thresholding of a stacked (3F x 3K) matrix A from its Gram matrix A^T A
    (3K x 3K): SVT(A) = A V_r G V_r^T, V_r the r right singular vectors whose values sigma exceed
    tau, G = diag((sigma - tau) / sigma) (V and sigma from the Gram matrix's eigen-decomposition).
    Returns V_r, V_r G and the thresholded nuclear norm."""
    evals, V = np.linalg.eigh(gram)
    sig = np.sqrt(np.maximum(evals, 0.0))
    shrunk = np.maximum(sig - tau, 0.0)
    keep = shrunk > 0
    Vk = V[:, keep]
    return Vk, Vk * (shrunk[keep] / sig[keep]), float(shrunk.sum())


def _gram(A: np.ndarray) -> np.ndarray:
    """A^T A (3K x 3K) of the stacked (3F x 3K) matrix given frames last as A (3, 3K, F)."""
    return A[0] @ A[0].T + A[1] @ A[1].T + A[2] @ A[2].T


def _threshold(A: np.ndarray, Vk: np.ndarray, Vg: np.ndarray, out: np.ndarray, scratch: np.ndarray | None = None
               ) -> np.ndarray:
    """Singular value thresholding of the stacked (3F x 3K) matrix given frames last as A (3, 3K, F)
    (A[i, :, k] is row i of frame k's A_k), with :func:`_shrinkage`'s V_r and V_r G (of the Gram
    matrix :func:`_gram`): the thresholded rows V_r G V_r^T A[i], into ``out``: one product with a 3K x 3K matrix, or two thin ones through the r kept directions when
    r < 3K / 2 (the thresholded rank is often low), the first into ``scratch`` (shaped like A) if given."""
    r = Vk.shape[1]
    if 2 * r < A.shape[1]:
        return np.matmul(Vk, np.matmul(Vg.T, A, out=None if scratch is None else scratch[:, :r]), out=out)
    return np.matmul(Vg @ Vk.T, A, out=out)


def _solve_A(A, Rot, s, S, R, wb, taus, work=None):
    """FISTA on tau ||A||_* + 1/2 sum_k || (P_k A_k S - R_k) sqrt(w_k) ||^2, one step per tau in taus,
    with P_k = s_k Rot_k[:2], starting from A and writing the answer over it. Frames last: A (3, 3K,
    F) (A[i, :, k] is row i of A_k), the rotations Rot (3, 3, F), the residuals R (2, L, F), the
    weights wb (L, F). ``work``: four arrays shaped like A, reused from pass to pass (arrays of
    10,000 frames take MB: allocated afresh each pass, their pages were mapped afresh, and the
    stage spent a twentieth of its time in the kernel doing so).

    The steps run in camera axes, on Rot_k A_k: stacking the frames' rotations gives a block-diagonal
    orthogonal matrix, so the nuclear norm, and the SVT with it, are unchanged, while P_k becomes
    s_k [I 0]: the data term acts on the first two rows only and the gradient needs no per-frame
    3 x 3 products. The turns into camera axes and back go a block of frames at a time (their
    temporaries stay in cache)."""
    m, F = A.shape[1:]
    blocks = frame_blocks(F, frames_last=True)
    # Lipschitz constant of the gradient: max_k s_k^2 * lambda_max(S diag(w_k) S^T) <= max_k s_k^2 * ||S||^2 max w
    lip = float((s**2 * wb.max(0)).max() * np.linalg.norm(S, 2) ** 2)
    if lip <= 0:
        return A
    step = 1.0 / lip
    wk = wb[0]
    uniform = bool((wb == wk).all())
    # One weight per frame (every bone seen, equal confidences): in the eigenbasis U of S S^T (A -> A U,
    # which the SVT commutes with) S S^T = U diag(lam) U^T is diagonal, and the descent step is a
    # product with a per-frame, per-column factor.
    lam, U = np.linalg.eigh(S @ S.T) if uniform else (None, np.eye(m))
    Y, A_prev, spare, turned = np.empty((4,) + A.shape) if work is None else work
    for b in blocks:
        np.matmul(U.T, per_frame_product(Rot[..., b], A[..., b], out=turned[..., b]), out=A_prev[..., b])
    if uniform:
        fac = 1.0 - (step * wk * s**2) * lam[:, None]  # (3K, F)
        US = U.T @ S
        c = join_blocks([(US @ R[..., b]) * (step * wk[b] * s[b]) for b in blocks])

        def descent(b):  # Y - step * gradient(Y) in place on frames b, the third row unchanged
            Yb = Y[:2, :, b]
            Yb *= fac[:, b]
            Yb += c[..., b]
    else:
        sw = s * wb  # (L, F)
        res, grad = np.empty(R.shape), np.empty((2, m, F))

        def descent(b):  # into two reused buffers: no array allocated per step
            rb, gb = res[..., b], grad[..., b]
            np.matmul(S.T, Y[:2, :, b], out=rb)  # (2, L, F)
            np.multiply(rb, s[b], out=rb)
            np.subtract(rb, R[..., b], out=rb)
            np.multiply(rb, sw[:, b], out=rb)
            np.matmul(S, rb, out=gb)
            np.multiply(gb, step, out=gb)
            Y[:2, :, b] -= gb
    # Each step is one sweep over the blocks of frames, a block's work done while it is in cache: its
    # thresholded rows (by the Gram matrix summed in the last sweep), the momentum, the next descent
    # and that point's Gram matrix. (On 100,000 frames, a pass over the whole sequence per operation
    # was 10 % slower; smaller blocks than the frames-last default were slower on 10,000 frames: numpy
    # runs a strided block row by row.) Three buffers in turn, nothing allocated per step: Y (the
    # descended point), A_prev, spare (``turned`` holds the thin SVT's intermediate product).
    np.copyto(Y, A_prev)
    gram = np.zeros((m, m))
    for b in blocks:
        descent(b)
        gram += _gram(Y[..., b])
    t = 1.0
    for k, tau in enumerate(taus):
        Vk, Vg, _ = _shrinkage(gram, step * tau)
        t_new = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
        beta = (t - 1.0) / t_new
        gram = np.zeros((m, m))
        for b in blocks:
            A_new = _threshold(Y[..., b], Vk, Vg, out=spare[..., b], scratch=turned[..., b])
            if k + 1 < len(taus):  # Y = A_new + beta (A_new - A_prev), descended, into Y's buffer
                Yb = Y[..., b]
                np.subtract(A_new, A_prev[..., b], out=Yb)
                Yb *= beta
                Yb += A_new
                descent(b)
                gram += _gram(Yb)
        spare, A_prev, t = A_prev, spare, t_new
    for b in blocks:
        per_frame_product(Rot[..., b], np.matmul(U, A_prev[..., b], out=turned[..., b]), transpose=True,
                           out=A[..., b])
    return A


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
    seen = seen_points(tracks)
    weights = np.where(seen, weights, 0.0)
    B0 = (C.T @ X0).T  # (3, L)
    Wb, wb = bone_observations(chain, tracks, weights)
    P, s, Rot = fit_cameras(Wb, B0.T, wb, return_rotation=True)
    k3 = int(n_basis) if n_basis else min(J - 1, 15)
    Q = _pose_basis(tracks, weights, P, X0, k3)
    S = Q @ C  # (3K, L)
    hist: dict[str, list[float]] = {"reprojection": []}

    # The iterations run frames last: A (3, 3K, F), bones (3, L, F), cameras P and rotations Rot
    # (2 or 3, 3, F), so that every per-frame product of small matrices is a few passes over
    # F-vectors (a stacked matmul of 10,000 3 x 3 matrices costs as much as ten such passes).
    Wl, wl = np.ascontiguousarray(Wb.transpose(2, 1, 0)), np.ascontiguousarray(wb.T)  # (2, L, F), (L, F)
    usable = (wl > 0).sum(0) >= 2
    c0 = (wl * (Wl[0] ** 2 + Wl[1] ** 2)).sum(0)
    P, Rot = np.ascontiguousarray(P.transpose(1, 2, 0)), np.ascontiguousarray(Rot.transpose(1, 2, 0))
    A = np.zeros((3, len(S), F))
    work = np.empty((4,) + A.shape)  # the FISTA steps' buffers, reused pass after pass
    nb = chain.n_bones
    Dt = np.ascontiguousarray(chain.D.T)  # (J, n_bones)
    Wt = np.ascontiguousarray(where_seen(tracks, seen).transpose(2, 1, 0))  # (2, J, F)
    wt = np.ascontiguousarray(weights.T)

    poses = np.empty((3, J, F))  # Xt, written over pass after pass

    def record(B, P):
        # Reprojection RMS with the best translation per frame
        Xt = np.matmul(Dt, B[:, :nb], out=poses)  # (3, J, F)
        rms, t = reprojection_with_translations(Wt, wt, Xt, P)
        hist["reprojection"].append(rms)
        if truth is not None and error_fn is not None:
            hist.setdefault("error_3d", []).append(float(error_fn(Xt.transpose(2, 1, 0), truth)))
        return Xt, t

    B0f = B0[:, :, None]
    blocks = frame_blocks(F, frames_last=True)

    def residuals(P):  # R = W C - P B0 (2, L, F)
        return join_blocks([Wl[..., b] - per_frame_product(P[..., b], B0f) for b in blocks])

    Xt, t = record(np.broadcast_to(B0f, B0.shape + (F,)), P)
    # The threshold scale: spectral norm of the gradient at A = 0 (where every singular value would
    # be thresholded away if tau were larger).
    R = residuals(P)
    g0 = per_frame_product(P, S @ (R * wl), transpose=True)  # (3, 3K, F)
    g0n = float(np.sqrt(max(np.linalg.eigvalsh(sum(g @ g.T for g in g0))[-1], 0)))
    tau_hi, tau_lo = tau_range[0] * g0n, tau_range[1] * g0n
    converged, it = False, 0
    B = np.broadcast_to(B0f, B0.shape + (F,))
    bones = np.empty((2,) + B.shape)  # this pass's bones and the last pass's, in turn
    b_rms = float(np.sqrt((B0**2).sum(0).mean()))
    for it in range(1, max_iter + 1):
        # Continuation: the first pass lowers tau from tau_hi to tau_lo; later passes, warm-started
        # from the previous A, stay at tau_lo.
        taus = np.geomspace(tau_hi, tau_lo, svt_steps) if it == 1 else np.full(max(svt_steps // 4, 1), tau_lo)
        R = R if it == 1 else residuals(P)
        A = _solve_A(A, Rot, s, S, R, wl, taus, work)
        # the bones B = A S + B0 (3, L, F), the camera fit's moments and how far the bones moved
        B_prev, B, moments, moved2 = B, bones[it % 2], [], 0.0
        for b in blocks:
            Bb = np.matmul(S.T, A[..., b], out=B[..., b])
            Bb += B0f
            moments.append(bone_moments(Wl[..., b], Bb, wl[:, b]))
            moved2 += float(((Bb - B_prev[..., b]) ** 2).sum())
        s, Rot = fit_to_moments(*join_blocks(moments), c0, usable, R0=Rot, n_iter=1)
        P = s * Rot[:2]
        Xt, t = record(B, P)
        r0, r1 = hist["reprojection"][-2], hist["reprojection"][-1]
        # Converged when the reprojection RMS changes by less than tol times the initial pose's
        # (at zero noise the RMS itself tends to 0) or the bones move by less than tol times their
        # RMS length (the paper: "only deform the 3D reconstruction less than 1 mm").
        moved = float(np.sqrt(moved2 / (F * B.shape[1])))
        if it >= 2 and (abs(r0 - r1) <= tol * max(hist["reprojection"][0], 1e-12) or moved <= tol * b_rms):
            converged = True
            break
    frames_first = lambda a: np.ascontiguousarray(a.transpose(2, 0, 1))  # noqa: E731
    return KCSResult(np.ascontiguousarray(Xt.transpose(2, 1, 0)), frames_first(P), s, frames_first(Rot), t,
                     frames_first(A), S, it, converged, hist)
