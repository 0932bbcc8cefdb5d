"""Refinement of a KCS reconstruction: constant but unknown bone lengths, temporal continuity, and
the initial pose as a weak prior that picks among the depth-sign ambiguities of orthographic views.

Why. Under a weak-perspective camera ``P_k = s_k R_k[:2]`` the image fixes, for every frame k and
bone b, the bone's in-image part ``x_kb[:2] = (W_k C)_b / s_k`` in camera axes; only its depth
``x_kb[2]`` is unknown. If the bone's length ``l_b`` is known, the depth is
``+-sqrt(l_b^2 - |x_kb[:2]|^2)``: one sign per bone and frame. The nuclear norm of Algorithm 1 only
stands in for this (bone lengths constant); a literal Algorithm 1 leaves depths near the initial
pose. This stage states it directly.

What. In camera axes (x_kb = R_k b_kb, so the per-frame camera rotation drops out) it minimises

    E = sum_kb w_kb huber(|s_k x_kb[:2] - (W_k C)_b|)                       robust data term (px^2)
      + lam_len    * s^2 sum_kb (|x_kb| - l_b)^2                             constant lengths
      + lam_smooth * s^2 sum_kb |x_(k+1)b - 2 x_kb + x_(k-1)b|^2             temporal continuity
      + lam_prior  * s^2 sum_kb |x_kb - R_k b0_b|^2                          weak prior (initial pose)

over the bones x (F, n_bones, 3) and the lengths l (n_bones,), with s the median camera scale, so
that every term is in squared image units. ``w_kb`` are the confidences of the bone's two joints
(0 where a point is missing); ``huber`` is r^2 below ``delta`` and 2 delta r - delta^2 above.
The cameras are those of the KCS stage (fixed here).

How. Block-coordinate descent, each block exact or safeguarded, so E never increases:

1. lengths: ``l_b = mean_k |x_kb|``, the exact minimiser given x;
2. depth signs: for each bone, depths ``+-sqrt(max(l_b^2 - |x_kb[:2]|^2, 0))``, the signs over all
   frames chosen by a Viterbi pass (states = the signs of two consecutive frames, so the
   acceleration term is exact; costs = prior + acceleration), vectorised over bones; a bone takes
   the proposal only if it lowers its part of E;
3. a Gauss-Newton step on x with iteratively reweighted Huber weights: E separates over bones, and
   for each bone the normal equations are banded (3 coordinates x F frames, band 6), solved by
   ``scipy.linalg.solveh_banded``; halved until E decreases, else rejected, per bone.

The start is whichever of the KCS bones and the initial pose has the lower E, so the result is never
worse (in E) than the initial pose. ``history["objective"]`` records E after every block.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import solveh_banded

__all__ = ["refine_bones", "RefineResult", "objective_terms"]


@dataclass
class RefineResult:
    """Refined bones in camera axes (F, n_bones, 3), lengths (n_bones,) and the objective history."""

    bones: np.ndarray
    lengths: np.ndarray
    n_iter: int
    converged: bool
    start: str
    history: dict[str, list[float]] = field(default_factory=dict)


@dataclass
class _Problem:
    Wb: np.ndarray  # (F, L, 2) observed 2D bones, 0 where unusable
    wb: np.ndarray  # (F, L) weights
    s: np.ndarray  # (F,) camera scales
    prior: np.ndarray  # (F, L, 3) prior bones in camera axes
    s2: float  # squared reference scale
    lam_len: float
    lam_smooth: float
    lam_prior: float
    delta: float


def _huber(r: np.ndarray, delta: float) -> np.ndarray:
    return np.where(r <= delta, r * r, 2.0 * delta * r - delta * delta)


def _accel(x: np.ndarray) -> np.ndarray:
    return x[2:] - 2.0 * x[1:-1] + x[:-2] if len(x) > 2 else np.zeros((0,) + x.shape[1:])


def objective_terms(pb: _Problem, x: np.ndarray, l: np.ndarray) -> dict[str, np.ndarray]:
    """Each term of E per bone, (L,) arrays (image units squared)."""
    r = np.linalg.norm(pb.s[:, None, None] * x[..., :2] - pb.Wb, axis=-1)
    data = (pb.wb * _huber(r, pb.delta)).sum(0)
    length = pb.lam_len * pb.s2 * ((np.linalg.norm(x, axis=-1) - l) ** 2).sum(0)
    smooth = pb.lam_smooth * pb.s2 * (_accel(x) ** 2).sum(axis=(0, 2))
    prior = pb.lam_prior * pb.s2 * ((x - pb.prior) ** 2).sum(axis=(0, 2))
    return {"data": data, "length": length, "smooth": smooth, "prior": prior}


def _energy(pb: _Problem, x: np.ndarray, l: np.ndarray) -> np.ndarray:
    t = objective_terms(pb, x, l)
    return t["data"] + t["length"] + t["smooth"] + t["prior"]


def _best_lengths(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x, axis=-1).mean(0)


def _sign_proposal(pb: _Problem, x: np.ndarray, l: np.ndarray) -> np.ndarray:
    """Depths of length l_b with signs from a second-order Viterbi pass over frames, all bones at once."""
    F, L = x.shape[:2]
    m = np.sqrt(np.maximum(l**2 - (x[..., :2] ** 2).sum(-1), 0.0))  # (F, L)
    z = np.stack([m, -m], axis=-1)  # (F, L, 2): state 0 = towards the viewer's +z
    unary = pb.lam_prior * pb.s2 * (z - pb.prior[..., 2:3]) ** 2  # (F, L, 2)
    if F < 3:
        sig = unary.argmin(-1)
    else:
        # acc[k] (L, 2, 2, 2) over signs of frames k, k+1, k+2
        acc = (z[:-2, :, :, None, None] - 2.0 * z[1:-1, :, None, :, None] + z[2:, :, None, None, :]) ** 2
        step = pb.lam_smooth * pb.s2 * acc + unary[2:, :, None, None, :]
        V = unary[0][:, :, None] + unary[1][:, None, :]  # (L, 2, 2) signs of frames (k, k+1)
        back = np.empty((F - 2, L, 2, 2), dtype=np.int8)
        for k in range(F - 2):
            cand = V[..., None] + step[k]  # (L, s_k, s_k+1, s_k+2)
            back[k] = cand.argmin(axis=1)
            V = cand.min(axis=1)
        sig = np.empty((F, L), dtype=np.int64)
        flat = V.reshape(L, 4).argmin(-1)
        sig[F - 2], sig[F - 1] = flat // 2, flat % 2
        ar = np.arange(L)
        for k in range(F - 3, -1, -1):
            sig[k] = back[k, ar, sig[k + 1], sig[k + 2]]
    depth = np.take_along_axis(z, sig[..., None], axis=-1)[..., 0]
    return np.concatenate([x[..., :2], depth[..., None]], axis=-1)


def _smooth_bands(F: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diagonals 0, 1, 2 of D2^T D2 for the (F-2) x F second-difference matrix D2."""
    if F < 3:
        return np.zeros(F), np.zeros(max(F - 1, 0)), np.zeros(max(F - 2, 0))
    ones = np.ones(F - 2)
    return np.convolve(ones, [1.0, 4.0, 1.0]), np.convolve(ones, [-2.0, -2.0]), ones


def _gauss_newton(pb: _Problem, x: np.ndarray, l: np.ndarray) -> np.ndarray:
    """Proposed x after one Gauss-Newton / IRLS step (per bone, banded normal equations)."""
    F, L = x.shape[:2]
    res = pb.s[:, None, None] * x[..., :2] - pb.Wb  # (F, L, 2)
    r = np.linalg.norm(res, axis=-1)
    h = pb.wb * np.where(r <= pb.delta, 1.0, pb.delta / np.maximum(r, 1e-300))  # IRLS weights
    nx = np.linalg.norm(x, axis=-1)
    u = x / np.maximum(nx, 1e-12)[..., None]
    kl, ks, kp = pb.lam_len * pb.s2, pb.lam_smooth * pb.s2, pb.lam_prior * pb.s2
    d0, d1, d2 = _smooth_bands(F)
    # gradient (half of dE/dx), per frame and bone
    g = np.zeros_like(x)
    g[..., :2] = (h * pb.s[:, None])[..., None] * res
    g += kl * (nx - l)[..., None] * u
    a = _accel(x)
    if F > 2:
        g[:-2] += ks * a
        g[1:-1] -= 2.0 * ks * a
        g[2:] += ks * a
    g += kp * (x - pb.prior)
    out = np.empty_like(x)
    hs2 = h * pb.s[:, None] ** 2
    for b in range(L):
        ab = np.zeros((7, 3 * F))  # upper banded storage, bandwidth 6
        diag = np.empty((F, 3))
        diag[:, :2] = hs2[:, b, None]
        diag[:, 2] = 0.0
        diag += kl * u[:, b] ** 2 + ks * d0[:, None] + kp
        ab[6] = diag.reshape(-1)
        off1 = np.zeros((F, 3))
        off1[:, 1] = kl * u[:, b, 0] * u[:, b, 1]
        off1[:, 2] = kl * u[:, b, 1] * u[:, b, 2]
        ab[5] = off1.reshape(-1)
        off2 = np.zeros((F, 3))
        off2[:, 2] = kl * u[:, b, 0] * u[:, b, 2]
        ab[4] = off2.reshape(-1)
        if F > 1:
            ab[3, 3:] = np.repeat(ks * d1, 3)
        if F > 2:
            ab[0, 6:] = np.repeat(ks * d2, 3)
        step = solveh_banded(ab, -g[:, b].reshape(-1), check_finite=False)
        out[:, b] = x[:, b] + step.reshape(F, 3)
    return out


def refine_bones(
    Wb: np.ndarray,
    wb: np.ndarray,
    scales: np.ndarray,
    prior: np.ndarray,
    init: np.ndarray,
    *,
    lam_len: float = 10.0,
    lam_smooth: float = 4.0,
    lam_prior: float = 1e-3,
    delta: float | None = None,
    max_iter: int = 50,
    tol: float = 1e-4,
    monitor: Any = None,
) -> RefineResult:
    """Minimise E (module docstring) from ``init``; all bone arrays in camera axes.

    Wb (F, L, 2) observed 2D bones (0 where unusable), wb (F, L) weights, scales (F,) camera
    scales, prior (F, L, 3) the initial pose's bones in camera axes, init (F, L, 3) starting bones
    (the KCS result in camera axes). ``delta`` is the Huber threshold in image units (default: 1 %
    of the median 2D extent of the bones). Stops when E decreases by less than ``tol`` relative
    over one sweep of the blocks. ``monitor(x)``, if given, is called with the start and after
    every sweep (for diagnostics such as the reprojection error).
    """
    s = np.asarray(scales, float)
    if delta is None:
        ext = np.median(np.linalg.norm(Wb, axis=-1).sum(-1)[wb.sum(-1) > 0]) if (wb > 0).any() else 1.0
        delta = max(0.01 * float(ext), 1e-9)
    pb = _Problem(Wb, wb, s, prior, float(np.median(s)) ** 2, lam_len, lam_smooth, lam_prior, float(delta))
    starts = {k: (v, _best_lengths(v)) for k, v in {"kcs": init, "initial pose": prior}.items()}
    # The KCS bones lifted onto the data: in-image parts from the tracks, lengths the median KCS
    # lengths, depths of those lengths with Viterbi signs.
    ok = wb > 0
    xy = np.where(ok[..., None], Wb / s[:, None, None], init[..., :2])
    l_med = np.median(np.linalg.norm(init, axis=-1), axis=0)
    lifted = _sign_proposal(pb, np.concatenate([xy, init[..., 2:]], -1), l_med)
    starts["kcs lifted"] = (lifted, _best_lengths(lifted))
    energies = {k: _energy(pb, *v).sum() for k, v in starts.items()}
    start = min(energies, key=energies.get)
    x, l = starts[start]
    x = x.copy()
    e = _energy(pb, x, l)
    hist: dict[str, list[float]] = {"objective": [float(e.sum())], "delta": [pb.delta]}
    if monitor is not None:
        monitor(x)
    converged, it = False, 0
    for it in range(1, max_iter + 1):
        e_begin = e.sum()
        # 1. lengths (exact)
        l = _best_lengths(x)
        e = _energy(pb, x, l)
        hist["objective"].append(float(e.sum()))
        # 2. depth signs (exact over signs, accepted per bone if better)
        xs = _sign_proposal(pb, x, l)
        es = _energy(pb, xs, l)
        take = es < e
        x = np.where(take[None, :, None], xs, x)
        e = np.where(take, es, e)
        hist["objective"].append(float(e.sum()))
        # 3. Gauss-Newton with backtracking, per bone
        xg = _gauss_newton(pb, x, l)
        alpha, todo = 1.0, np.ones(x.shape[1], bool)
        for _ in range(4):
            xt = x + alpha * (xg - x)
            et = _energy(pb, xt, l)
            ok = todo & (et < e)
            x = np.where(ok[None, :, None], xt, x)
            e = np.where(ok, et, e)
            todo &= ~ok
            if not todo.any():
                break
            alpha *= 0.5
        hist["objective"].append(float(e.sum()))
        if monitor is not None:
            monitor(x)
        if e_begin - e.sum() <= tol * max(e_begin, 1e-300):
            converged = True
            break
    return RefineResult(x, _best_lengths(x), it, converged, start, hist)
