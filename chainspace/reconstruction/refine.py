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
in time (:func:`chainspace.cameras.weak.smooth_scales`), fixed here.

How. Block-coordinate descent, each block exact or safeguarded, so E never increases:

1. lengths: ``l_b = mean_k |x_kb|``, the exact minimiser given x;
2. depth signs, one tree level at a time (parents first): for each bone, depths
   ``+-sqrt(max(l_b^2 - |x_kb[:2]|^2, 0))`` with the signs over all frames chosen by a Viterbi pass
   (states = the signs of two consecutive frames, so the acceleration term is exact; costs = prior
   + acceleration), vectorised over the bones of the level and, by min-plus prefix products in
   blocks, over frames (no Python loop over frames); a bone takes the proposal only if that
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

Note on the lengths block: eliminating the lengths inside the Gauss-Newton step (l = mean |x|, a
rank-one correction) converges in fewer sweeps to a lower E, but on the CMU subject-35 walks that
lower E has a larger 3D error (noise-free 20.4 -> 22.3 mm, 5 px 28.2 -> 45.6 mm, 3 walks x 3
cameras): there the objective, not the optimiser, limits the accuracy, so the alternation stays.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import solveh_banded

from ..blocks import frame_blocks

__all__ = ["refine_bones", "RefineResult", "objective_terms"]


# Unknowns per banded solve of the Gauss-Newton step (the bones one after the other; one bone a solve
# from 43,691 frames): the banded matrix, 56 bytes an unknown, stays small enough to be reused
# between solves instead of being mapped (and page-faulted) afresh.
SOLVE_GROUP = 2**17


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
        # Constant parts of the prior's rotation (see prior): for each bone with a parent, the
        # initial pose's parent direction u, and u.y and y x u for the bone's own initial-pose y.
        has = self.parent >= 0
        self.slot = np.cumsum(has) - 1  # bone -> its row in the arrays below
        y = self.glob[:, has]
        u = self.glob[:, self.parent[has]]
        u = u / np.maximum(np.sqrt(_dot(u, u)), 1e-300)[..., None]
        # coordinates first, (3, F, n): the prior's arithmetic then runs on contiguous (F, n)
        # arrays (on (F, n, 3) every product over the short last axis is several times slower)
        self.u_par, self.uy, self.yxu = _coords(u), _dot(u, y), _coords(_cross(y, u))
        self.glob_c = _coords(self.glob)
        self.Wb_c = _coords(self.Wb)

    def prior(self, x: np.ndarray, bones: Any = None) -> np.ndarray:
        """Prior bones (F, n, 3): the initial pose's bone turned by the smallest rotation that takes
        the initial pose's parent bone onto the current parent bone (so a knee keeps its bending
        direction relative to the thigh); the initial pose's own bone where there is no parent."""
        return np.moveaxis(self.prior_coords(x, bones), 0, -1)

    def prior_coords(self, x: np.ndarray, bones: Any = None, frames: slice | None = None) -> np.ndarray:
        """:meth:`prior` coordinates first, (3, F, n); only the rows ``frames`` of x and of the result
        (default: all, computed a block of frames at a time, :func:`chainspace.blocks.frame_blocks`)."""
        idx = np.arange(self.Wb.shape[1]) if bones is None else np.asarray(bones)
        if frames is None:
            F = len(x)
            out = np.empty((3, F, len(idx)))
            for fr in frame_blocks(F):
                out[:, fr] = self.prior_coords(x, idx, fr)
            return out
        has, q, u, y, yxu, uy = self._constants(idx, frames)
        if not len(has):
            return self.glob_c[:, frames][:, :, idx]
        v = _coords(np.take(x[frames], q, axis=1))
        v /= np.maximum(np.sqrt(_cdot(v, v)), 1e-300)
        c = _cdot(u, v)
        # Rodrigues for the rotation taking u to v, with w = u x v: y c + w x y + w (w.y) / (1 + c),
        # where w x y = v (u.y) - u (v.y) and w.y = v.(y x u)
        vy = _cdot(v, y)
        f = _cdot(v, yxu) / np.maximum(1.0 + c, 1e-9)
        w = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
        whole = len(has) == len(idx)
        out = np.empty(y.shape) if whole else self.glob_c[:, frames][:, :, idx]
        for i in range(3):
            r = y[i] * c
            r += v[i] * uy
            r -= u[i] * vy
            r += w[i] * f
            if whole:
                out[i] = r
            else:
                out[i][:, has] = r
        flip = ~(c > -0.999)  # parent turned about backwards: the rotation is ill-defined, keep y
        if flip.any():
            if whole:
                out[:, flip] = y[:, flip]
            else:
                out[:, :, has] = np.where(flip, y, out[:, :, has])
        return out

    def _constants(self, idx: np.ndarray, frames: slice) -> tuple:
        """The prior's constant arrays for the bones idx (rows ``frames``): which of them have a parent
        bone, those parents, and the initial-pose arrays of those bones."""
        has = np.flatnonzero(self.parent[idx] >= 0)
        k = self.slot[idx[has]]
        return (has, self.parent[idx[has]], self.u_par[:, frames][:, :, k], self.glob_c[:, frames][:, :, idx[has]],
                self.yxu[:, frames][:, :, k], self.uy[frames][:, k])


def _coords(a: np.ndarray) -> np.ndarray:
    """(..., 3) -> contiguous (3, ...)."""
    return np.ascontiguousarray(np.moveaxis(a, -1, 0))


def _cdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products of coordinates-first (3, ...) arrays."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products over the short last axis (a sum of products of the coordinates: about twice as
    fast as einsum or a sum over that axis)."""
    out = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        out += a[..., i] * b[..., i]
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) arrays (np.cross is slow on many short vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


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


def objective_terms(pb: _Problem, x: np.ndarray, l: np.ndarray, bones: Any = None) -> dict[str, np.ndarray]:
    """Each term of E per bone, (L,) arrays (image units squared); only ``bones`` if given."""
    idx = np.arange(x.shape[1]) if bones is None else np.asarray(bones)
    F = x.shape[0]
    data, length, smooth, prior = (np.zeros(len(idx)) for _ in range(4))
    for fr in frame_blocks(F):
        a, b = fr.start, fr.stop
        # the block's frames and the two after them, which its accelerations reach
        xe = _coords(np.take(x[a:min(b + 2, F)], idx, axis=1))  # (3, frames, n): sums over contiguous rows
        xc = xe[:, :b - a]
        Wb, wb = pb.Wb_c[:, a:b][:, :, idx], pb.wb[a:b][:, idx]
        s = pb.s[a:b, None]
        r = np.sqrt((s * xc[0] - Wb[0]) ** 2 + (s * xc[1] - Wb[1]) ** 2)
        data += (wb * _huber(r, pb.delta)).sum(0)
        length += ((np.sqrt(_cdot(xc, xc)) - l[idx]) ** 2).sum(0)
        acc = xe[:, 2:] - 2.0 * xe[:, 1:-1] + xe[:, :-2]
        smooth += _cdot(acc, acc).sum(0)
        d = xc - pb.prior_coords(x, idx, slice(a, b))
        prior += _cdot(d, d).sum(0)
    return {"data": data, "length": pb.lam_len * pb.s2 * length, "smooth": pb.lam_smooth * pb.s2 * smooth,
            "prior": pb.lam_prior * pb.s2 * prior}


def _energy(pb: _Problem, x: np.ndarray, l: np.ndarray, bones: Any = None) -> np.ndarray:
    t = objective_terms(pb, x, l, bones)
    return t["data"] + t["length"] + t["smooth"] + t["prior"]


def _accept(pb: _Problem, x: np.ndarray, l: np.ndarray, e: np.ndarray, proposal: np.ndarray,
            level: np.ndarray) -> np.ndarray:
    """Take the proposal (F, len(level), 3) for the bones of one level where it lowers E (lengths
    l fixed), in place on x and e (per bone): the bone's own terms plus the prior terms of its
    children (which hang on its direction). Bones of one level share no children, so each decision
    is exact. Returns the accepted mask."""
    kids = [pb.children[b] for b in level]
    affected = np.unique(np.concatenate([level] + kids)).astype(int)
    x_old = x[:, level].copy()
    x[:, level] = proposal
    e_new = _energy(pb, x, l, affected)
    e_new = dict(zip(affected.tolist(), e_new))
    delta = np.array([e_new[b] - e[b] + sum(e_new[k] - e[k] for k in kk) for b, kk in zip(level.tolist(), kids)])
    take = delta < 0
    x[:, level[~take]] = x_old[:, ~take]
    # a child's terms depend only on its own parent, so the values computed above are exact
    for b, kk, t in zip(level.tolist(), kids, take):
        if t:
            for k in [b] + kk.tolist():
                e[k] = e_new[k]
    return take


def _best_lengths(x: np.ndarray) -> np.ndarray:
    return np.sqrt(_dot(x, x)).mean(0)


def _sign_proposal(pb: _Problem, x: np.ndarray, l: np.ndarray, bones: Any) -> np.ndarray:
    """Proposed bones ``x[:, bones]`` (F, n, 3) with depths of length l_b, their signs from a
    second-order Viterbi pass over frames (vectorised over the bones). The prior is evaluated at x."""
    idx = np.asarray(bones)
    prior_z = pb.prior_coords(x, idx)[2].T  # (n, F)
    xb = x[:, idx]
    m = np.sqrt(np.maximum(l[idx] ** 2 - (xb[..., :2] ** 2).sum(-1), 0.0)).T  # (n, F)
    z = np.stack([m, -m])  # (2, n, F): state 0 = towards the viewer's +z
    unary = pb.lam_prior * pb.s2 * (z - prior_z) ** 2
    out = xb.copy()
    out[..., 2] = np.where(_viterbi(unary, z, pb.lam_smooth * pb.s2) == 0, m, -m).T
    return out


def _viterbi(unary: np.ndarray, z: np.ndarray, k_acc: float) -> np.ndarray:
    """(n, F) states (0 or 1) minimising sum_k unary[s_k, :, k] + k_acc (z[s_k] - 2 z[s_k+1] + z[s_k+2])^2
    for n independent chains (unary and z (2, n, F)).

    The states are pairs of consecutive signs (4 states, so the acceleration term is exact). Not
    the textbook forward pass with backtracking, which is a Python loop over frames: forward and
    backward min-plus messages from blocked prefix products (loops over about sqrt(F) steps
    vectorised over the blocks, :func:`_prefix_minplus`), and the state of each frame pair the
    minimiser of its min-marginal (the optimal path wherever it is unique).
    """
    n, F = unary.shape[1:]
    if F < 3:
        return unary.argmin(0)
    K = F - 2  # transitions between pairs (s_k, s_k+1) -> (s_k+1, s_k+2)
    T = np.empty((2, 2, 2, n, K))  # [a, bb, c]: pair (a, bb) -> (bb, c), chain, transition k
    for a in (0, 1):
        for bb in (0, 1):
            for c in (0, 1):
                T[a, bb, c] = k_acc * (z[a, :, :-2] - 2.0 * z[bb, :, 1:-1] + z[c, :, 2:]) ** 2 + unary[c, :, 2:]
    init = unary[:, None, :, 0] + unary[None, :, :, 1]
    fwd = _prefix_minplus(init, T)
    # backward: the same recursion on the reversed chain, whose pairs are (later, earlier) sign
    bwd = _prefix_minplus(np.zeros((2, 2, n)), T.transpose(2, 1, 0, 3, 4)[..., ::-1])
    p = (fwd + np.swapaxes(bwd, 1, 2)[::-1]).reshape(K + 1, 4, n).argmin(1)  # best pair state of frames (k, k + 1)
    return np.concatenate([p // 2, p[-1:] % 2]).T


def _prefix_minplus(init: np.ndarray, T: np.ndarray) -> np.ndarray:
    """All min-plus messages over pairs of consecutive states, m_0 = init (2, 2, n) and
    m_(k+1)[b, c] = min_a m_k[a, b] + T[a, b, c, :, k] for transitions T (2, 2, 2, n, K):
    (K + 1, 2, 2, n).

    In blocks of about sqrt(K) transitions: each block's min-plus product (a loop over the block
    length, vectorised over the blocks), the messages at the block starts from them (a loop over
    the blocks), then the messages inside all blocks at once (a loop over the block length). A
    pair (a, b) only goes to a pair (b, c), so a step is a minimum over the two values of a."""
    n, K = T.shape[3:]
    b = max(int(np.sqrt(K)), 1)
    nb = -(-K // b)
    # (b, a, bb, c, n, nb), the last block padded with zeros (the messages there are cut off)
    Tb = np.empty((b, 2, 2, 2, n, nb))
    full = K // b
    Tb[..., :full] = np.moveaxis(T[..., :full * b].reshape(2, 2, 2, n, full, b), -1, 0)
    if full < nb:
        rest = K - full * b
        Tb[:rest, ..., full] = np.moveaxis(T[..., full * b:], -1, 0)
        Tb[rest:, ..., full] = 0.0
    # prod[s, bb, c]: least cost from the pair s at a block's start to the pair (bb, c) after j + 1 steps
    prod = np.full((4, 2, 2, n, nb), np.inf)
    first = prod.reshape(2, 2, 2, 2, n, nb)
    for bb in (0, 1):
        first[:, bb, bb] = Tb[0, :, bb]
    for j in range(1, b):
        prod = np.minimum(prod[:, 0, :, None] + Tb[j, 0], prod[:, 1, :, None] + Tb[j, 1])
    prod = prod.reshape(4, 4, n, nb)
    starts = np.empty((nb, 4, n))  # messages at the block starts
    starts[0] = init.reshape(4, n)
    for i in range(1, nb):
        starts[i] = (starts[i - 1][:, None, :] + prod[..., i - 1]).min(0)
    msgs = np.empty((b + 1, 2, 2, n, nb))
    msgs[0] = np.moveaxis(starts, 0, -1).reshape(2, 2, n, nb)
    for j in range(b):
        m = msgs[j]
        np.minimum(m[0, :, None] + Tb[j, 0], m[1, :, None] + Tb[j, 1], out=msgs[j + 1])
    out = np.concatenate([msgs[:b].transpose(4, 0, 1, 2, 3).reshape(nb * b, 2, 2, n), msgs[b, ..., -1][None]])
    return out[:K + 1]


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
    y[:, b, c] (F, L, C) with weights w (F, L): one banded solve for all (the bones one after the
    other, so the matrix is block diagonal)."""
    F, L = y.shape[:2]
    if F < 3 or lam <= 0:
        return y.copy()
    d0, d1, d2 = _smooth_bands(F)
    ab = np.zeros((3, L, F))  # lower banded storage (see _gauss_newton)
    ab[0] = w.T + lam * d0 + 1e-9 * lam
    ab[1, :, :-1] = lam * d1
    ab[2, :, :-2] = lam * d2
    rhs = np.swapaxes(w[..., None] * y, 0, 1).reshape(L * F, -1)
    z = solveh_banded(ab.reshape(3, -1), rhs, lower=True, check_finite=False)
    return np.swapaxes(z.reshape(L, F, -1), 0, 1)


def _smooth_bands(F: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Diagonals 0, 1, 2 of D2^T D2 for the (F-2) x F second-difference matrix D2."""
    if F < 3:
        return np.zeros(F), np.zeros(max(F - 1, 0)), np.zeros(max(F - 2, 0))
    ones = np.ones(F - 2)
    return np.convolve(ones, [1.0, 4.0, 1.0]), np.convolve(ones, [-2.0, -2.0]), ones


def _gauss_newton(pb: _Problem, x: np.ndarray, l: np.ndarray) -> np.ndarray:
    """Proposed x after one Gauss-Newton / IRLS step (lengths fixed): the normal equations of every
    bone are banded (3 coordinates x F frames, bandwidth 6); several bones share one banded solve
    (one after the other, so the matrix is block diagonal)."""
    F, L = x.shape[:2]
    kl, ks, kp = pb.lam_len * pb.s2, pb.lam_smooth * pb.s2, pb.lam_prior * pb.s2
    d0, d1, d2 = _smooth_bands(F)
    # The gradient (half of dE/dx), IRLS weights h and unit bones u a block of frames at a time,
    # coordinates first (3, frames, L) (products over a short last axis are several times slower),
    # written out bone-major (L, F, 3), the order of the banded solve's unknowns: whole-sequence
    # temporaries would leave the cache, and at 100,000 frames cost a page fault every 4 kB.
    xc = _coords(x)
    ut, rhs, hs2 = np.empty((L, F, 3)), np.empty((L, F, 3)), np.empty((L, F))
    for fr in frame_blocks(F):
        xb, s = xc[:, fr], pb.s[fr, None]
        res = s * xb[:2] - pb.Wb_c[:, fr]  # (2, frames, L)
        r = np.sqrt(res[0] ** 2 + res[1] ** 2)
        h = pb.wb[fr] * np.where(r <= pb.delta, 1.0, pb.delta / np.maximum(r, 1e-300))
        nx = np.sqrt(_cdot(xb, xb))
        u = xb / np.maximum(nx, 1e-12)
        g = (kl * (nx - l)) * u + kp * (xb - pb.prior_coords(x, None, fr))
        g[:2] += (h * s) * res
        _add_smoothness_gradient(g, xc, fr, ks)
        ut[:, fr] = u.transpose(2, 1, 0)
        rhs[:, fr] = -g.transpose(2, 1, 0)
        hs2[:, fr] = (h * s**2).T
    step = np.empty_like(ut)
    for part in np.array_split(np.arange(L), min(-(-3 * F * L // SOLVE_GROUP), L)):
        up = ut[part]
        # lower banded storage, ab[d, i] = M[i + d, i] (LAPACK's banded Cholesky runs about twice as
        # fast on it as on the upper form)
        ab = np.zeros((7,) + up.shape)
        ab[0] = kl * up**2 + kp + ks * d0[:, None]
        ab[0, ..., :2] += hs2[part, :, None]
        ab[1, ..., 0] = kl * up[..., 0] * up[..., 1]
        ab[1, ..., 1] = kl * up[..., 1] * up[..., 2]
        ab[2, ..., 0] = kl * up[..., 0] * up[..., 2]
        ab[3, :, :-1] = ks * d1[:, None]
        ab[6, :, :-2] = ks * d2[:, None]
        ab[0] += 1e-12 * ab[0].max()  # a ridge: huge smoothness or length weights leave it singular
        step[part] = solveh_banded(ab.reshape(7, -1), rhs[part].reshape(-1), lower=True,
                                   check_finite=False).reshape(up.shape)
    return x + np.swapaxes(step, 0, 1)


def _add_smoothness_gradient(g: np.ndarray, xc: np.ndarray, frames: slice, ks: float) -> None:
    """Add the smoothness term's gradient ks (D2^T D2 x) to g (3, frames, L), the block ``frames`` of
    the whole gradient, from xc (3, F, L): frame i gets ks a_i - 2 ks a_(i-1) + ks a_(i-2), in that
    order, with the accelerations a_k = x_(k+2) - 2 x_(k+1) + x_k (0 <= k <= F - 3)."""
    F = xc.shape[1]
    f0, f1 = frames.start, frames.stop
    if F < 3:
        return
    k0, k1 = max(f0 - 2, 0), min(f1, F - 2)  # the accelerations the block reaches
    a = xc[:, k0 + 2:k1 + 2] - 2.0 * xc[:, k0 + 1:k1 + 1] + xc[:, k0:k1]
    for lag, factor, first, last in ((0, ks, f0, min(f1, F - 2)), (1, -2.0 * ks, max(f0, 1), min(f1, F - 1)),
                                     (2, ks, max(f0, 2), f1)):
        g[:, first - f0:last - f0] += factor * a[:, first - lag - k0:last - lag - k0]


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
        lam_smooth = min(max(0.1, (noise / (size / 3000.0)) ** 2), 1e8)  # capped: near-constant tracks
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
        lifted[:, level] = _sign_proposal(pb, lifted, l_med, level)
    # Over long gaps nothing in the data says more than the KCS bones: start there.
    lifted = np.where(known[..., None], lifted, init)
    starts["kcs lifted"] = (lifted, _best_lengths(lifted))
    energies = {k: _energy(pb, *v).sum() for k, v in starts.items()}
    start = min(energies, key=energies.get)
    x, l = starts[start][0].copy(), starts[start][1].copy()
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
                signs_useful |= bool(_accept(pb, x, l, e, _sign_proposal(pb, x, l, level), level).any())
        hist["objective"].append(float(e.sum()))
        # 3. Gauss-Newton step (prior directions frozen at x), halved until E drops, level by level
        xg = _gauss_newton(pb, x, l)
        for level in pb.levels:
            alpha, todo = 1.0, level
            for _ in range(4):
                take = _accept(pb, x, l, e, x[:, todo] + alpha * (xg[:, todo] - x[:, todo]), todo)
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
