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
      + lam_prior  * s^2 sum_kb |x_kb - p_kb(x)|^2                           weak prior (initial pose)

over the bones x (F, n_bones, 3) and the lengths l (n_bones,), with s the median camera scale, so
that every term is in squared image units. ``w_kb`` are the confidences of the bone's two joints
(0 where a point is missing); ``huber`` is r^2 below ``delta`` and 2 delta r - delta^2 above
(``delta`` = 3 x the track noise estimated from second differences in time, at least 1 % of the
subject's image size). The prior ``p_kb`` is the initial pose's bone in camera axes, ``R_k b0_b``;
for a bone hanging from a joint with a single child (a shin below a knee, a forearm below an
elbow) it is that bone turned by the smallest rotation taking the initial pose's parent bone onto
the current parent bone ``x_k,parent``, so the prior keeps the bend of a knee or elbow relative to
its parent rather than a global direction. The cameras are the KCS rotations with scales smoothed
in time (:func:`chainspace.camera.smooth_scales`), fixed here.

How. Block-coordinate descent, each block exact or safeguarded, so E never increases:

1. lengths: ``l_b = mean_k |x_kb|``, the exact minimiser given x;
2. depth signs, one tree level at a time (parents first): for each bone, depths
   ``+-sqrt(max(l_b^2 - |x_kb[:2]|^2, 0))`` with the signs over all frames chosen by a Viterbi pass
   (states = the signs of two consecutive frames, so the acceleration term is exact; costs = prior
   + acceleration), vectorised over the bones of the level; a bone takes the proposal only if that
   lowers its terms plus its children's prior terms (bones of a level share no children, so the
   per-bone decisions are exact);
3. a Gauss-Newton step on x (iteratively reweighted Huber weights, prior directions frozen): for
   each bone the normal equations are banded (3 coordinates x F frames, band 6) and solved by
   ``scipy.linalg.solveh_banded``; level by level, a bone's step is halved until E drops, else
   rejected.

Start: the lowest-E of the KCS bones, the initial pose, and the KCS bones lifted onto the data
(in-image parts from the tracks smoothed in time and interpolated over gaps, median KCS lengths,
Viterbi signs), so the result is never worse in E than the initial pose. ``history["objective"]``
records E after every block.
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
    glob: np.ndarray  # (F, L, 3) initial-pose bones in camera axes (the global prior)
    s2: float  # squared reference scale
    lam_len: float
    lam_smooth: float
    lam_prior: float
    delta: float
    parent: Any = None  # (L,) parent bone whose direction carries the prior, -1: global prior

    def __post_init__(self):
        L = self.Wb.shape[1]
        self.parent = np.full(L, -1) if self.parent is None else np.asarray(self.parent, int)
        depth = np.zeros(L, int)
        for _ in range(L):
            depth = np.where(self.parent >= 0, depth[np.maximum(self.parent, 0)] + 1, 0)
        self.levels = [np.flatnonzero(depth == d) for d in range(depth.max() + 1)]
        self.children = [np.flatnonzero(self.parent == b) for b in range(L)]

    def prior(self, x: np.ndarray, bones: Any = None) -> np.ndarray:
        """Prior bones (F, n, 3): the initial pose's bone turned by the smallest rotation that takes
        the initial pose's parent bone onto the current parent bone (so a knee keeps its bending
        direction relative to the thigh); the initial pose's own bone where there is no parent."""
        idx = np.arange(self.Wb.shape[1]) if bones is None else np.asarray(bones)
        g = self.glob[:, idx]
        has = np.flatnonzero(self.parent[idx] >= 0)
        if not len(has):
            return g
        q = self.parent[idx[has]]
        u = self.glob[:, q]
        v = x[:, q]
        u = u / np.maximum(np.sqrt((u * u).sum(-1, keepdims=True)), 1e-300)
        v = v / np.maximum(np.sqrt((v * v).sum(-1, keepdims=True)), 1e-300)
        w = _cross(u, v)
        c = (u * v).sum(-1, keepdims=True)
        y = g[:, has]
        # Rodrigues for the rotation taking u to v: y c + w x y + w (w.y) / (1 + c)
        rot = y * c + _cross(w, y) + w * (w * y).sum(-1, keepdims=True) / np.maximum(1.0 + c, 1e-9)
        out = g.copy()
        out[:, has] = np.where(c > -0.999, rot, y)
        return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) arrays (np.cross is slow on many short vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def image_size_and_noise(Wb: np.ndarray, wb: np.ndarray) -> tuple[float, float]:
    """The subject's size in the image (median over frames of the summed 2D bone lengths / 2,
    roughly its height) and the track noise per coordinate, estimated from second differences in
    time of the 2D bones (robust: the median absolute value; a bone differences two points)."""
    seen = wb > 0
    per_frame = np.linalg.norm(Wb, axis=-1).sum(-1)
    size = float(np.median(per_frame[seen.any(-1)])) / 2.0 if seen.any() else 1.0
    if len(Wb) < 3:
        return size, 0.0
    ok = seen[2:] & seen[1:-1] & seen[:-2]
    d2 = (Wb[2:] - 2.0 * Wb[1:-1] + Wb[:-2])[ok]
    if d2.size == 0:
        return size, 0.0
    noise = 1.4826 * float(np.median(np.abs(d2))) / np.sqrt(6.0) / np.sqrt(2.0)
    return size, noise


def _huber(r: np.ndarray, delta: float) -> np.ndarray:
    return np.where(r <= delta, r * r, 2.0 * delta * r - delta * delta)


def _accel(x: np.ndarray) -> np.ndarray:
    return x[2:] - 2.0 * x[1:-1] + x[:-2] if len(x) > 2 else np.zeros((0,) + x.shape[1:])


def objective_terms(pb: _Problem, x: np.ndarray, l: np.ndarray, bones: Any = None) -> dict[str, np.ndarray]:
    """Each term of E per bone, (L,) arrays (image units squared); only ``bones`` if given."""
    idx = np.arange(x.shape[1]) if bones is None else np.asarray(bones)
    xb = x[:, idx]
    r = np.linalg.norm(pb.s[:, None, None] * xb[..., :2] - pb.Wb[:, idx], axis=-1)
    data = (pb.wb[:, idx] * _huber(r, pb.delta)).sum(0)
    length = pb.lam_len * pb.s2 * ((np.linalg.norm(xb, axis=-1) - l[idx]) ** 2).sum(0)
    smooth = pb.lam_smooth * pb.s2 * (_accel(xb) ** 2).sum(axis=(0, 2))
    prior = pb.lam_prior * pb.s2 * ((xb - pb.prior(x, idx)) ** 2).sum(axis=(0, 2))
    return {"data": data, "length": length, "smooth": smooth, "prior": prior}


def _energy(pb: _Problem, x: np.ndarray, l: np.ndarray, bones: Any = None) -> np.ndarray:
    t = objective_terms(pb, x, l, bones)
    return t["data"] + t["length"] + t["smooth"] + t["prior"]


def _accept(pb: _Problem, x: np.ndarray, l: np.ndarray, e: np.ndarray, proposal: np.ndarray,
            level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Take the proposal for the bones of one level where it lowers E: their own terms plus the
    prior terms of their children (which hang on their direction). Bones of one level share no
    children, so each decision is exact. Returns x, e (per bone) and the accepted mask."""
    kids = [pb.children[b] for b in level]
    affected = np.unique(np.concatenate([level] + kids)).astype(int)
    xt = x.copy()
    xt[:, level] = proposal[:, level]
    e_new = e.copy()
    e_new[affected] = _energy(pb, xt, l, affected)
    delta = np.array([e_new[b] - e[b] + (e_new[k] - e[k]).sum() for b, k in zip(level, kids)])
    take = delta < 0
    if take.any():
        on = level[take]
        x = x.copy()
        x[:, on] = proposal[:, on]
        upd = np.unique(np.concatenate([on] + [pb.children[b] for b in on])).astype(int)
        e = e.copy()
        e[upd] = _energy(pb, x, l, upd)
    return x, e, take


def _best_lengths(x: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x, axis=-1).mean(0)


def _sign_proposal(pb: _Problem, x: np.ndarray, l: np.ndarray, bones: Any = None) -> np.ndarray:
    """x with the depths of ``bones`` (default all) set to length l_b, their signs from a
    second-order Viterbi pass over frames (vectorised over bones). The prior is evaluated at x."""
    idx = np.arange(x.shape[1]) if bones is None else np.asarray(bones)
    prior_z = pb.prior(x, idx)[..., 2:3]
    out = x.copy()
    xb = x[:, idx]
    F, L = xb.shape[:2]
    m = np.sqrt(np.maximum(l[idx] ** 2 - (xb[..., :2] ** 2).sum(-1), 0.0))  # (F, L)
    z = np.stack([m, -m], axis=-1)  # (F, L, 2): state 0 = towards the viewer's +z
    unary = pb.lam_prior * pb.s2 * (z - prior_z) ** 2  # (F, L, 2)
    if F < 3:
        sig = unary.argmin(-1)
    else:
        # acc[k] (L, 2, 2, 2) over signs of frames k, k+1, k+2
        acc = (z[:-2, :, :, None, None] - 2.0 * z[1:-1, :, None, :, None] + z[2:, :, None, None, :]) ** 2
        step = pb.lam_smooth * pb.s2 * acc + unary[2:, :, None, None, :]
        V = unary[0][:, :, None] + unary[1][:, None, :]  # (L, 2, 2) signs of frames (k, k+1)
        back = np.empty((F - 2, L, 2, 2), dtype=bool)
        s0, s1 = np.ascontiguousarray(step[:, :, 0]), np.ascontiguousarray(step[:, :, 1])
        for k in range(F - 2):
            # V[l, s_k, s_k+1] -> V[l, s_k+1, s_k+2]: min over the two values of s_k
            c0 = V[:, 0, :, None] + s0[k]
            c1 = V[:, 1, :, None] + s1[k]
            np.less(c1, c0, out=back[k])
            V = np.minimum(c0, c1)
        sig = np.empty((F, L), dtype=np.int64)
        flat = V.reshape(L, 4).argmin(-1)
        sig[F - 2], sig[F - 1] = flat // 2, flat % 2
        ar = np.arange(L)
        for k in range(F - 3, -1, -1):
            sig[k] = back[k, ar, sig[k + 1], sig[k + 2]]
    out[:, idx, 2] = np.take_along_axis(z, sig[..., None], axis=-1)[..., 0]
    return out


def _interpolated_xy(Wb: np.ndarray, wb: np.ndarray, s: np.ndarray, fallback: np.ndarray,
                     max_gap: int = 30) -> np.ndarray:
    """In-image bone parts (F, L, 2) from the data where a bone is seen; over gaps of up to
    ``max_gap`` frames linearly interpolated in time, over longer gaps (and before the first or after
    the last sighting) taken from ``fallback`` (the KCS bones, which the visible joints constrain).
    Also returns the (F, L) mask of the entries that come from the data (seen or short gaps)."""
    xy = Wb / s[:, None, None]
    out = fallback[..., :2].copy()
    known = np.zeros(wb.shape, bool)
    frames = np.arange(len(Wb))
    for b in range(Wb.shape[1]):
        ok = wb[:, b] > 0
        if not ok.any():
            continue
        seen_at = frames[ok]
        interp = np.stack([np.interp(frames, seen_at, xy[ok, b, c]) for c in range(2)], -1)
        nxt = np.searchsorted(seen_at, frames)
        prev_f = seen_at[np.clip(nxt - 1, 0, len(seen_at) - 1)]
        next_f = seen_at[np.clip(nxt, 0, len(seen_at) - 1)]
        short = ok | ((next_f - prev_f <= max_gap + 1) & (nxt > 0) & (nxt < len(seen_at)))
        out[:, b] = np.where(short[:, None], interp, out[:, b])
        known[:, b] = short
    return out, known


def _smooth_series(y: np.ndarray, w: np.ndarray, lam: float) -> np.ndarray:
    """argmin_z sum_k w_k |z_k - y_k|^2 + lam |z_(k+1) - 2 z_k + z_(k-1)|^2 for every series
    y[:, b, c] (F, L, C) with weights w (F, L): one banded solve per series."""
    F = len(y)
    if F < 3 or lam <= 0:
        return y.copy()
    d0, d1, d2 = _smooth_bands(F)
    out = np.empty_like(y)
    for b in range(y.shape[1]):
        ab = np.zeros((3, F))
        ab[2] = w[:, b] + lam * d0 + 1e-9 * lam
        ab[1, 1:] = lam * d1
        ab[0, 2:] = lam * d2
        out[:, b] = solveh_banded(ab, w[:, b, None] * y[:, b], check_finite=False)
    return out


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
    g += kp * (x - pb.prior(x))
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
    lam_smooth: float | None = None,
    lam_prior: float = 1e-3,
    delta: float | None = None,
    max_iter: int = 50,
    tol: float = 1e-4,
    monitor: Any = None,
    parent_bone: Any = None,
) -> RefineResult:
    """Minimise E (module docstring) from ``init``; all bone arrays in camera axes.

    Wb (F, L, 2) observed 2D bones (0 where unusable), wb (F, L) weights, scales (F,) camera
    scales, prior (F, L, 3) the initial pose's bones in camera axes, init (F, L, 3) starting bones
    (the KCS result in camera axes). ``delta`` is the Huber threshold in image units (default:
    3 x the estimated track noise, at least 1 % of the subject's image size). ``lam_smooth``
    defaults to max(0.1, (noise / (size / 3000))^2) with the noise estimated from the tracks: tuned
    on 120 Hz motion capture (lower it for slower frame rates). Stops when E decreases by less than ``tol`` relative
    over one sweep of the blocks. ``monitor(x)``, if given, is called with the start and after
    every sweep (for diagnostics such as the reprojection error).
    """
    s = np.asarray(scales, float)
    size, noise = image_size_and_noise(Wb, wb)
    if lam_smooth is None:
        # As much as the track noise is large compared with the frame-to-frame acceleration of
        # human motion at 120 Hz (about 1/3000 of the subject's size), squared; a little always.
        lam_smooth = max(0.1, (noise / (size / 3000.0)) ** 2)
    if delta is None:
        delta = max(3.0 * noise, 0.01 * size, 1e-12)
    pb = _Problem(Wb, wb, s, prior, float(np.median(s)) ** 2, lam_len, lam_smooth, lam_prior, float(delta),
                  parent_bone)
    starts = {k: (v, _best_lengths(v)) for k, v in {"kcs": init, "initial pose": prior}.items()}
    # The KCS bones lifted onto the data: in-image parts from the tracks (smoothed in time), lengths
    # the median KCS lengths, depths of those lengths with Viterbi signs, level by level down the tree.
    xy, known = _interpolated_xy(Wb, wb, s, init)
    xy = _smooth_series(xy, wb * (s**2 / pb.s2)[:, None], lam_smooth)
    lifted = np.concatenate([xy, init[..., 2:]], -1)
    # lengths: median KCS length over the frames where the bone is seen (unseen ones are guesses)
    l_kcs = np.where(wb > 0, np.linalg.norm(init, axis=-1), np.nan)
    l_med = np.where((wb > 0).any(0), np.nanmedian(np.where((wb > 0).any(0), l_kcs, 0.0), axis=0),
                     np.median(np.linalg.norm(init, axis=-1), axis=0))
    for level in pb.levels:
        lifted = _sign_proposal(pb, lifted, l_med, level)
    # Over long gaps nothing in the data says more than the KCS bones: start there.
    lifted = np.where(known[..., None], lifted, init)
    starts["kcs lifted"] = (lifted, _best_lengths(lifted))
    energies = {k: _energy(pb, *v).sum() for k, v in starts.items()}
    start = min(energies, key=energies.get)
    x, l = starts[start]
    x = x.copy()
    e = _energy(pb, x, l)
    hist: dict[str, list[float]] = {"objective": [float(e.sum())], "delta": [pb.delta], "noise": [noise],
                                    "lam_smooth": [float(lam_smooth)]}
    if monitor is not None:
        monitor(x)
    converged, it, signs_useful = False, 0, True
    for it in range(1, max_iter + 1):
        e_begin = e.sum()
        # 1. lengths (exact)
        l = _best_lengths(x)
        e = _energy(pb, x, l)
        hist["objective"].append(float(e.sum()))
        # 2. depth signs, level by level (exact over the signs of a level given its parents, taken
        # per bone if E drops); once no bone takes them, only every fourth sweep tries again
        if signs_useful or it % 4 == 0:
            signs_useful = False
            for level in pb.levels:
                x, e, take = _accept(pb, x, l, e, _sign_proposal(pb, x, l, level), level)
                signs_useful |= bool(take.any())
        hist["objective"].append(float(e.sum()))
        # 3. Gauss-Newton step (prior directions frozen at x), halved until E drops, level by level
        xg = _gauss_newton(pb, x, l)
        for level in pb.levels:
            alpha, todo = 1.0, level
            for _ in range(4):
                x, e, take = _accept(pb, x, l, e, x + alpha * (xg - x), todo)
                todo = todo[~take]
                if not len(todo):
                    break
                alpha *= 0.5
        hist["objective"].append(float(e.sum()))
        if monitor is not None:
            monitor(x)
        if e_begin - e.sum() <= tol * max(e_begin, 1e-300):
            converged = True
            break
    return RefineResult(x, _best_lengths(x), it, converged, start, hist)
