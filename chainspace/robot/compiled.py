"""The solver's most frequent problems compiled (numba): Levenberg-Marquardt on many independent rows, each
one configuration's joint angles against its own target under a held view (:func:`lm_rows`); and on a
sequence's joint angles together with the one camera that every frame shares (:func:`lm_shared`), also
under the motion prior that ties each joint to its path through neighbouring frames (``_smooth_lm``).

Why: the branch search, the depth flips and the sequential IK solve thousands of small problems (one per
frame and start) a few dozen times per fit; in numpy each step of all of them took some forty array
operations of a few floats per row, about 5 microseconds a row and step, most of a fit's time (issue 19).
Here each row runs its own loop over the joints, its kinematics and its small normal equations in compiled
code (about 1 microsecond a row and step for a 6-axis arm), and the rows are shared among threads. The
fits that move the camera too (the perspective fit's, the 3D fit's alignment) took another 40 % of a
pinhole fit in numpy, some 19 microseconds a frame and iteration; compiled, about 6. With the motion prior
(the choice among candidates, the perspective fit's smoothing) the joint angles' block is banded rather
than block-diagonal, and is factored by a banded Cholesky (:func:`_banded_step`).

The steps are those of :func:`chainspace.robot.solver._sequence_lm` (same damping, same stopping rules, the
same iterations at which starts that met are merged; the camera's part of a shared step by the same Schur
complement), its numbers the same to rounding; rounding can send a
row elsewhere along a direction its target leaves flat, at the same cost. Covered: the batched kinematics
(:class:`chainspace.robot.kinematics._BatchedKinematics`: revolute, continuous, prismatic and mimic joints)
seen through a weak-perspective or 3D view (:class:`chainspace.robot.views._View`) or a pinhole camera
(:class:`chainspace.robot.views._PinholeView`). Anything else, and everything where numba cannot be
imported, stays with the numpy solver.

Compiled on first use and cached on disk (numba's ``cache=True``): the first fit after an install spends
some seconds compiling. ``CHAINSPACE_THREADS`` sets the number of threads (default: the usable cores):
a solve's rows are shared among them (:func:`run_rows`), and so are the independent fits that a robot fit
tries from its several starts (:func:`imap_tasks`), each with the numbers it gives on one thread.
"""

from __future__ import annotations

import functools
import os
import threading
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import ChainspaceError

try:  # pragma: no cover - numba is a dependency; the numpy solver is the fallback where it cannot load
    import numba
except ImportError:  # pragma: no cover
    numba = None

FIXED, REVOLUTE, PRISMATIC, CONTINUOUS = 0, 1, 2, 3


class CompiledModel:
    """The batched kinematics of a :class:`~chainspace.robot.kinematics.RobotKinematics` as flat arrays
    for the compiled solver: the placed joints in order, their parents, placements in the parent joint's
    frame (rotation, translation), kind, axis, configuration index, scaling and offset; each tracked
    point's joint and place in it; which velocity columns move which point; the joint limits."""

    def __init__(self, robot) -> None:
        b = robot._batch
        kinds = {"fixed": FIXED, "revolute": REVOLUTE, "prismatic": PRISMATIC, "continuous": CONTINUOUS}
        self.joints = np.array(b.joints, np.int64)
        self.parents = np.asarray(b.parents, np.int64)
        self.Mr = np.ascontiguousarray(b.M[:, :3, :3], dtype=float)
        self.Mt = np.ascontiguousarray(b.M[:, :3, 3], dtype=float)
        self.kind = np.array([kinds[k] for k in b.kind], np.int64)
        self.axis = np.ascontiguousarray(b.axis, dtype=float)
        self.MrK, self.MrKK = self.Mr @ b.K, self.Mr @ b.KK  # Rodrigues' terms, in the parent's axes
        self.idx_q, self.column = np.asarray(b.idx_q, np.int64), np.asarray(b.column_of, np.int64)
        self.scaling, self.offset = np.asarray(b.scaling, float), np.asarray(b.offset, float)
        self.point_joint = np.asarray(robot._parent_joint, np.int64)
        self.in_parent = np.ascontiguousarray(robot._in_parent[:, :3], dtype=float)
        self.carried = np.ascontiguousarray(robot._carried_by)
        self.limited = np.asarray(robot.limited)
        self.lower, self.upper = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
        # each Jacobian column's velocity (a mimic's folds onto its leader's), each velocity's first
        # configuration entry, and whether that is a continuous joint's (cos, sin) pair
        self.velocity = np.argmax(robot._fold, axis=1).astype(np.int64)
        self.q_of_v = np.argmax(robot._qv, axis=0).astype(np.int64)
        self.pair = np.asarray(robot.continuous_v)

    @staticmethod
    def of(robot) -> "CompiledModel | None":
        """The compiled model of ``robot``, made once and kept on it; None where the compiled solver does
        not cover it: no numba, kinematics looped over Pinocchio, or a joint other than one turning or
        sliding axis (each Jacobian column must move one velocity, each velocity be a 1-dof joint's
        entry or a continuous joint's (cos, sin) pair)."""
        if "_compiled" not in robot.__dict__:
            fold, qv = robot._fold, robot._qv
            ok = numba is not None and robot._batch is not None and ((fold != 0).sum(1) == 1).all() and \
                (fold.max(1) == 1).all() and np.array_equal(qv.sum(0), 1 + robot.continuous_v) and \
                (qv.sum(1) == 1).all()
            robot._compiled = CompiledModel(robot) if ok and _compiles() else None
        return robot._compiled

    def args(self) -> tuple:
        """The arrays as one tuple, in the order the compiled functions unpack them (``model``)."""
        return (self.joints, self.parents, self.Mr, self.Mt, self.kind, self.axis, self.MrK, self.MrKK, self.idx_q,
                self.column, self.scaling, self.offset, self.point_joint, self.in_parent, self.carried, self.limited,
                self.lower, self.upper, self.velocity, self.q_of_v, self.pair)


def _njit(f):
    # error_model='numpy': a division by zero gives inf as numpy's does, without a check in every loop
    return numba.njit(cache=True, nogil=True, error_model="numpy")(f) if numba is not None else f


def _njit_inline(f):
    """:func:`_njit` for the per-point helpers, inlined where they are called: as calls, their dozen array
    arguments each time cost more than the work (the UR10's row step 2.0 -> 2.85 microseconds)."""
    return numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(f) if numba is not None else f


@_njit
def _place(q, joints, parents, Mr, Mt, kind, axis, MrK, MrKK, idx_q, scaling, offset, R, p):
    """World rotations R (njoints, 3, 3) and origins p (njoints, 3) of the placed joints at q (nq,),
    written in place (joint 0, the universe, is the identity); MrK, MrKK: each joint's placement rotation
    times its axis's cross-product matrix K and K^2."""
    E = np.empty((3, 3))  # the joint's placement in its parent, times its own motion
    for j in joints:
        a = parents[j]
        if kind[j] == REVOLUTE or kind[j] == CONTINUOUS:
            if kind[j] == REVOLUTE:
                th = scaling[j] * q[idx_q[j]] + offset[j]
                c, s = np.cos(th), np.sin(th)
            else:
                c, s = q[idx_q[j]], q[idx_q[j] + 1]
            for i in range(3):  # Mr (I + s K + (1 - c) K^2): Rodrigues about the joint's axis
                for k in range(3):
                    E[i, k] = Mr[j, i, k] + s * MrK[j, i, k] + (1.0 - c) * MrKK[j, i, k]
        else:
            E[:] = Mr[j]
        for i in range(3):
            p[j, i] = p[a, i] + R[a, i, 0] * Mt[j, 0] + R[a, i, 1] * Mt[j, 1] + R[a, i, 2] * Mt[j, 2]
            for k in range(3):
                R[j, i, k] = R[a, i, 0] * E[0, k] + R[a, i, 1] * E[1, k] + R[a, i, 2] * E[2, k]
        if kind[j] == PRISMATIC:
            d = scaling[j] * q[idx_q[j]] + offset[j]
            for i in range(3):
                p[j, i] += d * (R[j, i, 0] * axis[j, 0] + R[j, i, 1] * axis[j, 1] + R[j, i, 2] * axis[j, 2])


@_njit
def _points(R, p, point_joint, in_parent, pos):
    """The chain's points pos (J, 3), in place, from the joints' placements."""
    for k in range(len(point_joint)):
        j = point_joint[k]
        for i in range(3):
            pos[k, i] = p[j, i] + R[j, i, 0] * in_parent[k, 0] + R[j, i, 1] * in_parent[k, 1] + \
                R[j, i, 2] * in_parent[k, 2]


@_njit
def _predict(M, T, pinhole, f, cxy, x0, x1, x2, i):
    """Coordinate i of a point's prediction: the weak view's s R[:D] = M, T; or the pinhole camera's rotation M
    (3, 3), translation T (3,), focal f and principal point cxy (a depth within a nanometre of 0 held there)."""
    if not pinhole:
        return M[i, 0] * x0 + M[i, 1] * x1 + M[i, 2] * x2 + T[i]
    z = M[2, 0] * x0 + M[2, 1] * x1 + M[2, 2] * x2 + T[2]
    z = z if abs(z) > 1e-9 else 1e-9
    return f * (M[i, 0] * x0 + M[i, 1] * x1 + M[i, 2] * x2 + T[i]) / z + cxy[i]


@_njit
def _evaluate(q, tz, w, M, T, pinhole, f, cxy, delta, model, R, p, pos, res):
    """Residuals res (J, D) of q (nq,) under the view (:func:`_predict`), in place, and the robust cost
    sum_j w_j rho(|res_j|) (plain squares for delta < 0)."""
    joints, parents, Mr, Mt, kind, axis, MrK, MrKK, idx_q, column, scaling, offset, point_joint, in_parent = model[:14]
    _place(q, joints, parents, Mr, Mt, kind, axis, MrK, MrKK, idx_q, scaling, offset, R, p)
    _points(R, p, point_joint, in_parent, pos)
    D = tz.shape[1]
    cost = 0.0
    for k in range(len(pos)):
        n2 = 0.0
        for i in range(D):
            res[k, i] = _predict(M, T, pinhole, f, cxy, pos[k, 0], pos[k, 1], pos[k, 2], i) - tz[k, i]
            n2 += res[k, i] * res[k, i]
        rn = np.sqrt(n2)
        if delta < 0 or rn <= delta:
            cost += w[k] * rn * rn
        else:
            cost += w[k] * (2 * delta * rn - delta * delta)
    return cost


@_njit_inline
def _joint_axes(R, joints, scaling, axis, Wa):
    """Each placed joint's axis in world axes, its scaling included, into Wa (njoints, 3)."""
    for j in joints:
        for i in range(3):
            Wa[j, i] = scaling[j] * (R[j, i, 0] * axis[j, 0] + R[j, i, 1] * axis[j, 1] + R[j, i, 2] * axis[j, 2])


@_njit_inline
def _point_rows(k, w, M, T, pinhole, f, delta, free, joints, kind, column, carried, velocity, p, pos, res, Wa, Mk,
                Jq):
    """Point k's rows of the Jacobian of the residuals by the joint velocities, Jq (D, nv) (held
    directions' columns zero), and d prediction / d point Mk (D, 3), in place, at the placements p, pos;
    returns its IRLS weight (Huber with threshold delta; delta < 0: squares). The model's arrays come
    unpacked (joints, kind, column, carried, velocity)."""
    D = res.shape[1]
    n2 = 0.0
    for i in range(D):
        n2 += res[k, i] * res[k, i]
    rn = np.sqrt(n2)
    ww = w[k] if delta < 0 or rn <= delta else w[k] * delta / max(rn, 1e-300)
    if pinhole:  # d pixels / d point: (f / z) (I | -(y_x, y_y) / z) R at the point's y = R x + t
        x0, x1, x2 = pos[k, 0], pos[k, 1], pos[k, 2]
        z = M[2, 0] * x0 + M[2, 1] * x1 + M[2, 2] * x2 + T[2]
        z = z if abs(z) > 1e-9 else 1e-9
        a = f / z
        for i in range(2):
            yz = (M[i, 0] * x0 + M[i, 1] * x1 + M[i, 2] * x2 + T[i]) / z
            for m in range(3):
                Mk[i, m] = a * M[i, m] - a * yz * M[2, m]
    else:
        for i in range(D):
            for m in range(3):
                Mk[i, m] = M[i, m]
    Jq[:] = 0.0
    for j in joints:
        c = column[j]
        v = velocity[c]
        if kind[j] == FIXED or not carried[k, c] or not free[v]:
            continue
        if kind[j] != PRISMATIC:  # the point's velocity w x (x - o)
            x0, x1, x2 = pos[k, 0] - p[j, 0], pos[k, 1] - p[j, 1], pos[k, 2] - p[j, 2]
            v0, v1, v2 = Wa[j, 1] * x2 - Wa[j, 2] * x1, Wa[j, 2] * x0 - Wa[j, 0] * x2, Wa[j, 0] * x1 - Wa[j, 1] * x0
        else:
            v0, v1, v2 = Wa[j, 0], Wa[j, 1], Wa[j, 2]
        for i in range(D):
            Jq[i, v] += Mk[i, 0] * v0 + Mk[i, 1] * v1 + Mk[i, 2] * v2
    return ww


@_njit
def _normal_equations(w, M, T, pinhole, f, delta, free, model, R, p, pos, res, H, g, Jq, Wa, Mk):
    """H (nv, nv) and g (nv,) of the IRLS-weighted residuals at the placements R, p (held directions'
    columns zero), in place; Jq (D, nv), Wa (njoints, 3) and Mk (D, 3) are scratch. Each point's rows
    are :func:`_point_rows`', written out here: called, even inlined, they made a row's step of the
    UR10 (:func:`lm_rows`) 15-20 % slower (2.0 -> 2.3-2.4 microseconds)."""
    joints, kind, axis, column, scaling, carried, velocity = model[0], model[4], model[5], model[9], model[10], \
        model[14], model[18]
    nv, D = len(free), res.shape[1]
    H[:] = 0.0
    g[:] = 0.0
    for j in joints:  # each joint's axis in world axes (its scaling included)
        for i in range(3):
            Wa[j, i] = scaling[j] * (R[j, i, 0] * axis[j, 0] + R[j, i, 1] * axis[j, 1] + R[j, i, 2] * axis[j, 2])
    for k in range(len(pos)):
        if w[k] == 0.0:
            continue
        n2 = 0.0
        for i in range(D):
            n2 += res[k, i] * res[k, i]
        rn = np.sqrt(n2)
        ww = w[k] if delta < 0 or rn <= delta else w[k] * delta / max(rn, 1e-300)
        if pinhole:  # d pixels / d point: (f / z) (I | -(y_x, y_y) / z) R at the point's y = R x + t
            x0, x1, x2 = pos[k, 0], pos[k, 1], pos[k, 2]
            z = M[2, 0] * x0 + M[2, 1] * x1 + M[2, 2] * x2 + T[2]
            z = z if abs(z) > 1e-9 else 1e-9
            a = f / z
            for i in range(2):
                yz = (M[i, 0] * x0 + M[i, 1] * x1 + M[i, 2] * x2 + T[i]) / z
                for m in range(3):
                    Mk[i, m] = a * M[i, m] - a * yz * M[2, m]
        else:
            for i in range(D):
                for m in range(3):
                    Mk[i, m] = M[i, m]
        Jq[:] = 0.0
        for j in joints:
            c = column[j]
            v = velocity[c]
            if kind[j] == FIXED or not carried[k, c] or not free[v]:
                continue
            if kind[j] != PRISMATIC:  # the point's velocity w x (x - o)
                x0, x1, x2 = pos[k, 0] - p[j, 0], pos[k, 1] - p[j, 1], pos[k, 2] - p[j, 2]
                v0, v1, v2 = Wa[j, 1] * x2 - Wa[j, 2] * x1, Wa[j, 2] * x0 - Wa[j, 0] * x2, Wa[j, 0] * x1 - Wa[j, 1] * x0
            else:
                v0, v1, v2 = Wa[j, 0], Wa[j, 1], Wa[j, 2]
            for i in range(D):
                Jq[i, v] += Mk[i, 0] * v0 + Mk[i, 1] * v1 + Mk[i, 2] * v2
        for a in range(nv):
            for i in range(D):
                g[a] += ww * Jq[i, a] * res[k, i]
            for b in range(a, nv):
                s = 0.0
                for i in range(D):
                    s += Jq[i, a] * Jq[i, b]
                H[a, b] += ww * s
    for a in range(nv):
        for b in range(a):
            H[a, b] = H[b, a]


@_njit
def _solve(A, b, x):
    """x = A^-1 b for a small square A by Gaussian elimination with partial pivoting (A, b overwritten)."""
    n = len(b)
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[piv, c]):
                piv = r
        if piv != c:
            for k in range(n):
                A[c, k], A[piv, k] = A[piv, k], A[c, k]
            b[c], b[piv] = b[piv], b[c]
        for r in range(c + 1, n):
            f = A[r, c] / A[c, c]
            for k in range(c, n):
                A[r, k] -= f * A[c, k]
            b[r] -= f * b[c]
    for r in range(n - 1, -1, -1):
        s = b[r]
        for k in range(r + 1, n):
            s -= A[r, k] * x[k]
        x[r] = s / A[r, r]


@_njit
def _integrate(q, dq, free, q_of_v, pair, limited, lower, upper, out):
    """out = q moved by -dq on the free velocities (a continuous joint's (cos, sin) turned, renormalised to
    first order as Pinocchio's ``integrate`` does), then clipped into the limits."""
    out[:] = q
    for v in range(len(dq)):
        if not free[v]:
            continue
        i = q_of_v[v]
        if pair[v]:
            co, si = np.cos(-dq[v]), np.sin(-dq[v])
            c, s = q[i] * co - q[i + 1] * si, q[i + 1] * co + q[i] * si
            n2 = c * c + s * s
            out[i], out[i + 1] = c * (3 - n2) / 2, s * (3 - n2) / 2
        else:
            out[i] = q[i] - dq[v]
            if limited[i]:
                out[i] = min(max(out[i], lower[i]), upper[i])


@_njit
def lm_rows(q, tz, w, M, T, pinhole, f, cxy, free, delta, tol, it_from, it_to, lam, active, last_it, rn, pos_out,
            kept, more, model):
    """Iterations it_from..it_to of :func:`chainspace.robot.solver._sequence_lm` (view held, rows independent)
    on every active row, in place: q (N, nq), lam, active (N,), the iteration at which each row
    stopped, and the residual norms rn (N, J) and points pos_out (N, J, 3) at its q. tz (N, J, D)
    targets, w (N, J) weights, M (N, D, 3) and T (N, D) each row's view (pinhole: M (N, 3, 3), T (N, 3) and
    f, cxy; :func:`_predict`), free (N, nv), delta < 0: squares.

    kept = (H (N, nv, nv), g (N, nv), cost (N,), ready (N,)): a row's normal equations and cost at its q,
    valid where ready. With ``more`` (a later call goes on from here) each row still active keeps them,
    and skips its points and residuals, which the next call does not need; a row that starts ready then
    does not evaluate its q again. The steps are the same either way."""
    limited, lower, upper, q_of_v, pair = model[15], model[16], model[17], model[19], model[20]
    H_kept, g_kept, c_kept, ready = kept
    N, J, D = tz.shape
    nq, nv = q.shape[1], free.shape[1]
    nj = len(model[1])
    R, p, Wa = np.zeros((nj, 3, 3)), np.zeros((nj, 3)), np.zeros((nj, 3))
    R[0, 0, 0] = R[0, 1, 1] = R[0, 2, 2] = 1.0
    pos, res, res_t = np.empty((J, 3)), np.empty((J, D)), np.empty((J, D))
    H, g, Hq, rhs, dq = np.empty((nv, nv)), np.empty(nv), np.empty((nv, nv)), np.empty(nv), np.empty(nv)
    Jq, qt, qr, Mk = np.empty((D, nv)), np.empty(nq), np.empty(nq), np.empty((D, 3))
    for r in range(N):
        if not active[r]:
            continue
        qr[:] = q[r]
        if ready[r]:  # H, g and the cost of qr from the call before; its placements are not at hand
            H[:] = H_kept[r]
            g[:] = g_kept[r]
            c_r = c_kept[r]
            stale = placed = False
        else:
            c_r = _evaluate(qr, tz[r], w[r], M[r], T[r], pinhole, f, cxy, delta, model, R, p, pos, res)
            stale = placed = True
        for it in range(it_from, it_to + 1):
            if stale:  # the placements R, p are those of qr: its last evaluation
                _normal_equations(w[r], M[r], T[r], pinhole, f, delta, free[r], model, R, p, pos, res, H, g, Jq, Wa,
                                  Mk)
                stale = False
            mean = 0.0
            for a in range(nv):
                mean += H[a, a]
            floor = 1e-6 * mean / nv + 1e-30
            for a in range(nv):
                for b in range(nv):
                    Hq[a, b] = H[a, b]
                Hq[a, a] += lam[r] * (H[a, a] + floor) + (0.0 if free[r, a] else 1.0)
                rhs[a] = g[a]
            _solve(Hq, rhs, dq)
            _integrate(qr, dq, free[r], q_of_v, pair, limited, lower, upper, qt)
            placed = False  # R, p, pos: the trial's until it is accepted
            c_t = _evaluate(qt, tz[r], w[r], M[r], T[r], pinhole, f, cxy, delta, model, R, p, pos, res_t)
            if c_t <= c_r:
                rel = (c_r - c_t) / max(c_r, 1e-300)
                qr[:] = qt
                res[:] = res_t
                c_r = c_t
                stale = placed = True
                lam[r] = max(lam[r] / 5, 1e-12)
                if rel < tol or c_t < 1e-24:
                    active[r] = False
            else:
                lam[r] *= 10
                if lam[r] > 1e10:
                    active[r] = False
            last_it[r] = it
            if not active[r]:
                break
        q[r] = qr
        if more and active[r]:
            if stale:
                _normal_equations(w[r], M[r], T[r], pinhole, f, delta, free[r], model, R, p, pos, res, H, g, Jq, Wa,
                                  Mk)
            H_kept[r] = H
            g_kept[r] = g
            c_kept[r] = c_r
            ready[r] = True
            continue
        if not placed:  # the last trial was rejected: qr's points and residuals again
            _evaluate(qr, tz[r], w[r], M[r], T[r], pinhole, f, cxy, delta, model, R, p, pos, res)
        for k in range(J):
            n2 = 0.0
            for i in range(D):
                n2 += res[k, i] * res[k, i]
            rn[r, k] = np.sqrt(n2)
            pos_out[r, k] = pos[k]


@_njit_inline
def _camera_rows(k, pos, R, t, sf, pinhole, fit_focal, fit_centre, free_view, Jc, v):
    """Point k's rows of the Jacobian of its prediction by the shared camera's step, Jc (D, nc), in place
    (held parameters' columns zero). Weak (``sf`` the scale s; s (R x)[:D] + t[:D]): rotation vector,
    scale, translation; pinhole (``sf`` the focal f; f (y_x, y_y) / y_z + c at y = R x + t): rotation
    vector, translation, then log f and the principal point where fitted: the steps of ``_View.moved``
    and ``_PinholeView.moved``, whose rotation turns R x by w x (R x). v (3,): scratch, left R x."""
    D = Jc.shape[0]
    for i in range(3):
        v[i] = R[i, 0] * pos[k, 0] + R[i, 1] * pos[k, 1] + R[i, 2] * pos[k, 2]
    Jc[:] = 0.0
    if pinhole:
        z = v[2] + t[2]
        z = z if abs(z) > 1e-9 else 1e-9
        a = sf / z
        for i in range(2):  # P = d pixels / d y: row i a (e_i - y_i / z e_z); P (-[v]^) and P
            P0, P1, P2 = a * (i == 0), a * (i == 1), -a * (v[i] + t[i]) / z
            Jc[i, 0] = P2 * v[1] - P1 * v[2]
            Jc[i, 1] = P0 * v[2] - P2 * v[0]
            Jc[i, 2] = P1 * v[0] - P0 * v[1]
            Jc[i, 3], Jc[i, 4], Jc[i, 5] = P0, P1, P2
        n = 6
        if fit_focal:  # d u / d log f = f (y_x, y_y) / y_z
            Jc[0, n] = a * (v[0] + t[0])
            Jc[1, n] = a * (v[1] + t[1])
            n += 1
        if fit_centre:
            Jc[0, n] = 1.0
            Jc[1, n + 1] = 1.0
    else:  # row i of -s [v]^: s (e_i x v); then v_i, and e_i
        for i in range(D):
            b, c = (i + 1) % 3, (i + 2) % 3
            Jc[i, b] = sf * v[c]
            Jc[i, c] = -sf * v[b]
            Jc[i, 3] = v[i]
            Jc[i, 4 + i] = 1.0
    for c in range(Jc.shape[1]):
        if not free_view[c]:
            for i in range(D):
                Jc[i, c] = 0.0


@_njit
def _rotation_step(w, R, out):
    """out = exp(w^) R (Rodrigues; the rotation vector's step of the views' ``moved``)."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    a, b = (1.0, 0.5) if th < 1e-8 else (np.sin(th) / th, (1 - np.cos(th)) / (th * th))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    E = np.eye(3) + a * K + b * (K @ K)
    for i in range(3):
        for k in range(3):
            out[i, k] = E[i, 0] * R[0, k] + E[i, 1] * R[1, k] + E[i, 2] * R[2, k]


@_njit
def _view_arrays(R, t, sf, pinhole, D, M, T):
    """The camera as :func:`_predict` takes it, into M, T: weak s R[:D], t[:D]; pinhole R, t."""
    for i in range(3 if pinhole else D):
        for k in range(3):
            M[i, k] = R[i, k] if pinhole else sf * R[i, k]
        T[i] = t[i]


@_njit
def _evaluate_all(q, tz, w, M, T, pinhole, f, cxy, delta, model, Rp, pp, pos, res, cost):
    """:func:`_evaluate` of every frame: placements Rp (F, njoints, 3, 3), pp, points, residuals and costs."""
    for r in range(len(q)):
        cost[r] = _evaluate(q[r], tz[r], w[r], M, T, pinhole, f, cxy, delta, model, Rp[r], pp[r], pos[r], res[r])


@_njit
def _shared_blocks(w, M, T, R, t, sf, pinhole, fit_focal, fit_centre, delta, free, free_view, model, Rp, pp, pos,
                   res, Hqq, Hqc, gq, Hcc, gc):
    """The normal equations of every frame's joint angles and the one shared camera, in place: per frame
    Hqq (F, nv, nv), Hqc (F, nv, nc), gq (F, nv); the camera's Hcc (nc, nc), gc (nc,) summed over frames."""
    F, J, D = res.shape
    nv, nc = free.shape[1], len(free_view)
    Jq, Jc, Mk, Wa, v = np.empty((D, nv)), np.empty((D, nc)), np.empty((D, 3)), np.zeros((Rp.shape[1], 3)), np.empty(3)
    H, B, g = np.empty((nv, nv)), np.empty((nv, nc)), np.empty(nv)  # one frame's blocks
    Hcc[:] = 0.0
    gc[:] = 0.0
    joints, kind, column, carried, velocity = model[0], model[4], model[9], model[14], model[18]
    for r in range(F):
        wr, fr, pr, xr, er = w[r], free[r], pp[r], pos[r], res[r]
        H[:] = 0.0
        B[:] = 0.0
        g[:] = 0.0
        _joint_axes(Rp[r], joints, model[10], model[5], Wa)
        for k in range(J):
            if wr[k] == 0.0:
                continue
            ww = _point_rows(k, wr, M, T, pinhole, sf, delta, fr, joints, kind, column, carried, velocity, pr, xr, er,
                             Wa, Mk, Jq)
            _camera_rows(k, xr, R, t, sf, pinhole, fit_focal, fit_centre, free_view, Jc, v)
            for i in range(D):
                e = ww * er[k, i]
                for a in range(nv):
                    wa = ww * Jq[i, a]
                    g[a] += Jq[i, a] * e
                    for b in range(a, nv):
                        H[a, b] += wa * Jq[i, b]
                    for c in range(nc):
                        B[a, c] += wa * Jc[i, c]
                for c in range(nc):
                    wc = ww * Jc[i, c]
                    gc[c] += Jc[i, c] * e
                    for d in range(c, nc):
                        Hcc[c, d] += wc * Jc[i, d]
        for a in range(nv):
            gq[r, a] = g[a]
            for b in range(nv):
                Hqq[r, a, b] = H[a, b] if b >= a else H[b, a]
            for c in range(nc):
                Hqc[r, a, c] = B[a, c]
    for c in range(nc):
        for d in range(c):
            Hcc[c, d] = Hcc[d, c]


@_njit
def _schur_step(Hqq, Hqc, gq, Hcc, gc, lam, free, free_view, dq, dc, K):
    """The damped Gauss-Newton step of every frame's joint angles and the shared camera, the frames
    eliminated by a Schur complement (``_sequence_lm``'s damping: lam times each diagonal entry, a frame's
    plus a millionth of its mean; held directions pinned), into dq (F, nv) and dc (nc,), signed as
    :func:`_integrate` and the views' ``moved`` take them: q <- q - dq, camera <- camera + dc. K (F, nv,
    nc + 1): scratch, left each frame's damped block's inverse times [Hqc | gq]."""
    F, nv = gq.shape
    nc = len(gc)
    L = np.empty((nv, nv))
    for r in range(F):
        mean = 0.0
        for a in range(nv):
            mean += Hqq[r, a, a]
        floor = 1e-6 * mean / nv + 1e-30
        for a in range(nv):  # the frame's damped block, positive definite: Cholesky, once for all columns
            for b in range(a + 1):
                s = Hqq[r, a, b]
                if a == b:
                    s += lam * (Hqq[r, a, a] + floor) + (0.0 if free[r, a] else 1.0)
                for m in range(b):
                    s -= L[a, m] * L[b, m]
                L[a, b] = np.sqrt(s) if a == b else s / L[b, b]
        for col in range(nc + 1):  # Hq^-1 [Hqc | gq], column by column
            for a in range(nv):
                s = Hqc[r, a, col] if col < nc else gq[r, a]
                for m in range(a):
                    s -= L[a, m] * K[r, m, col]
                K[r, a, col] = s / L[a, a]
            for a in range(nv - 1, -1, -1):
                s = K[r, a, col]
                for m in range(a + 1, nv):
                    s -= L[m, a] * K[r, m, col]
                K[r, a, col] = s / L[a, a]
    _camera_then_joints(Hqc, gq, Hcc, gc, lam, free, free_view, K, dq, dc)


@_njit
def _camera_then_joints(Hqc, gq, Hcc, gc, lam, free, free_view, K, dq, dc):
    """The end of a damped step with the shared camera (:func:`_schur_step`, :func:`_banded_step`), given
    K (F, nv, nc + 1), the joint block's damped inverse times [Hqc | gq]: the camera's step dc from its
    Schur complement (damped by lam times its diagonal, held parameters pinned), then the joints' dq."""
    F, nv = gq.shape
    nc = len(gc)
    schur, rhs = Hcc.copy(), gc.copy()
    for c in range(nc):
        schur[c, c] += lam * (Hcc[c, c] + 1e-12) + (0.0 if free_view[c] else 1.0)
    for r in range(F):
        for c in range(nc):
            for d in range(nc):
                s = 0.0
                for a in range(nv):
                    s += Hqc[r, a, c] * K[r, a, d]
                schur[c, d] -= s
            s = 0.0
            for a in range(nv):
                s += K[r, a, c] * gq[r, a]
            rhs[c] -= s
    _solve(schur, rhs, dc)
    for c in range(nc):
        dc[c] = -dc[c] if free_view[c] else 0.0
    for r in range(F):
        for a in range(nv):
            s = K[r, a, nc]
            for c in range(nc):
                s += K[r, a, c] * dc[c]
            dq[r, a] = s if free[r, a] else 0.0


@_njit
def _angles(q, q_of_v, pair, out):
    """``RobotKinematics.angles`` of q (F, nq) into out (F, nv): each velocity's coordinate, a continuous
    joint's (cos, sin) as its angle unwrapped along the frames (``np.unwrap``'s steps)."""
    F, nv = out.shape
    for v in range(nv):
        i = q_of_v[v]
        if not pair[v]:
            for r in range(F):
                out[r, v] = q[r, i]
            continue
        out[0, v] = np.arctan2(q[0, i + 1], q[0, i])
        shift, last = 0.0, out[0, v]
        for r in range(1, F):
            a = np.arctan2(q[r, i + 1], q[r, i])
            dd = a - last
            ddmod = (dd + np.pi) % (2 * np.pi) - np.pi
            if ddmod == -np.pi and dd > 0:
                ddmod = np.pi
            if abs(dd) >= np.pi:
                shift += ddmod - dd
            out[r, v] = a + shift
            last = a


@_njit
def _prior_terms(prior, q, free, gq):
    """The motion prior q' P q of :func:`chainspace.robot.solver._smooth_lm` on the angles q (F, nv)
    (:func:`_angles`; P in ``prior`` (F, S + 1, nv): P[f, s, a] couples joint a at frame f to itself at frame
    f + s, the only entries :func:`chainspace.robot.solver._motion_prior` makes); with gq (F, nv) given,
    its gradient half P q is added there and the held directions' gradient zeroed. Returns q' P q."""
    F, nv = q.shape
    quad = 0.0
    for r in range(F):
        for a in range(nv):
            pq = g = prior[r, 0, a] * q[r, a]  # its row of P q: the entries ahead count twice in q' P q
            for s in range(1, prior.shape[1]):
                if r + s < F:
                    ahead = prior[r, s, a] * q[r + s, a]
                    pq += 2.0 * ahead
                    g += ahead
                if r >= s:
                    g += prior[r - s, s, a] * q[r - s, a]
            quad += q[r, a] * pq
            if gq.shape[0]:
                gq[r, a] = gq[r, a] + g if free[r, a] else 0.0
    return quad


@_njit
def _band_cholesky(A):
    """Cholesky factor L of a symmetric positive definite band matrix, in place: A (N, u + 1) holds entry
    (i, i - k) of the lower band at A[i, k], and then L's."""
    N, u = A.shape[0], A.shape[1] - 1
    for j in range(N):
        s = A[j, 0]
        for k in range(1, min(j, u) + 1):
            s -= A[j, k] * A[j, k]
        ljj = np.sqrt(s)
        A[j, 0] = ljj
        for i in range(j + 1, min(N, j + u + 1)):
            s = A[i, i - j]
            for m in range(max(i - u, 0), j):
                s -= A[i, i - m] * A[j, j - m]
            A[i, i - j] = s / ljj


@_njit
def _band_solve(L, B):
    """B <- (L L')^-1 B in place, column by column, L a band Cholesky factor as :func:`_band_cholesky`
    leaves it."""
    N, u = L.shape[0], L.shape[1] - 1
    for col in range(B.shape[1]):
        for i in range(N):
            s = B[i, col]
            for m in range(max(i - u, 0), i):
                s -= L[i, i - m] * B[m, col]
            B[i, col] = s / L[i, 0]
        for i in range(N - 1, -1, -1):
            s = B[i, col]
            for m in range(i + 1, min(N, i + u + 1)):
                s -= L[m, m - i] * B[m, col]
            B[i, col] = s / L[i, 0]


@_njit
def _banded_step(Hqq, Hqc, gq, Hcc, gc, prior, lam, free, free_view, dq, dc, A, K):
    """:func:`_schur_step` with the motion prior: the joint angles' block is every frame's Hqq plus the
    prior (``prior`` as :func:`_prior_terms` takes it), banded (a joint couples to itself S frames on),
    factored by a banded Cholesky in A (F nv, S nv + 1): A[i, k] holds entry (i, i - k). The damping is
    ``_smooth_lm``'s: lam times each diagonal entry plus a billionth of their mean, held joint directions
    pinned by 1e12, held camera directions by 1. K (F, nv, nc + 1): scratch, as :func:`_schur_step`'s.
    Same signs."""
    F, nv = gq.shape
    nc = len(gc)
    N = F * nv
    sol = K.reshape(N, nc + 1)  # row r nv + a: frame r's joint a
    mean = 0.0
    for r in range(F):
        for a in range(nv):
            mean += Hqq[r, a, a] + prior[r, 0, a]
    floor = 1e-9 * mean / N
    A[:] = 0.0
    for r in range(F):
        for a in range(nv):
            i = r * nv + a
            for b in range(a):
                A[i, a - b] = Hqq[r, a, b]
            d = Hqq[r, a, a] + prior[r, 0, a]
            A[i, 0] = d + lam * (d + floor) + (0.0 if free[r, a] else 1e12)
            for s in range(1, prior.shape[1]):
                if r >= s:
                    A[i, s * nv] = prior[r - s, s, a]
            for c in range(nc):
                sol[i, c] = Hqc[r, a, c]
            sol[i, nc] = gq[r, a]
    _band_cholesky(A)
    _band_solve(A, sol)  # the band's inverse times [Hqc | gq]
    _camera_then_joints(Hqc, gq, Hcc, gc, lam, free, free_view, K, dq, dc)


@_njit_inline
def _moved_camera(dc, R, t, sf, cxy, pinhole, fit_focal, fit_centre, D, R_t, t_t, c_t):
    """The camera after the step dc, as ``_View.moved`` / ``_PinholeView.moved`` make it: R_t, t_t, c_t in
    place; returns its scale (weak) or focal (pinhole)."""
    _rotation_step(dc[:3], R, R_t)
    t_t[:] = t
    c_t[:] = cxy
    if not pinhole:
        for i in range(D):
            t_t[i] += dc[4 + i]
        return sf + dc[3]
    for i in range(3):
        t_t[i] += dc[3 + i]
    n = 7 if fit_focal else 6
    if fit_centre:
        c_t[0] += dc[n]
        c_t[1] += dc[n + 1]
    return sf * np.exp(dc[6]) if fit_focal else sf


@_njit
def lm_shared(q, tz, w, free, free_view, delta, tol, max_iter, R, t, sf, cxy, pinhole, fit_focal, fit_centre,
              prior, rn_out, pos_out, model):
    """:func:`chainspace.robot.solver._sequence_lm` with one camera shared by every frame and free to move
    (its steps, damping and stopping rules): q (F, nq) and the camera R (3, 3), t (3,; weak: t[:D] the
    translation), cxy (2,) in place; ``sf`` the weak camera's scale or the pinhole's focal. tz (F, J, D)
    targets, w (F, J) weights, free (F, nv), free_view (nc,), delta < 0: squares. With a motion prior
    (``prior`` (F, S + 1, nv), :func:`_prior_terms`; none: (0, S + 1, nv)) it is
    :func:`chainspace.robot.solver._smooth_lm` instead (its objective, damping and banded step). Writes the
    residual norms rn_out (F, J) and points pos_out (F, J, 3); returns (sf, iterations, converged)."""
    limited, lower, upper, q_of_v, pair = model[15], model[16], model[17], model[19], model[20]
    F, J, D = tz.shape
    nq, nv, nc = q.shape[1], free.shape[1], len(free_view)
    nj = len(model[1])
    Rp, pp, Rp_t, pp_t = np.zeros((F, nj, 3, 3)), np.zeros((F, nj, 3)), np.zeros((F, nj, 3, 3)), np.zeros((F, nj, 3))
    for r in range(F):
        for i in range(3):
            Rp[r, 0, i, i] = Rp_t[r, 0, i, i] = 1.0
    pos, res, pos_t, res_t = np.empty((F, J, 3)), np.empty((F, J, D)), np.empty((F, J, 3)), np.empty((F, J, D))
    cost, cost_t = np.empty(F), np.empty(F)
    Hqq, Hqc, gq = np.empty((F, nv, nv)), np.empty((F, nv, nc)), np.empty((F, nv))
    Hcc, gc, dq, dc, K = np.empty((nc, nc)), np.empty(nc), np.empty((F, nv)), np.empty(nc), np.empty((F, nv, nc + 1))
    M, T, q_t = np.zeros((3, 3)), np.zeros(3), np.empty((F, nq))
    R_t, t_t, c_t = np.empty((3, 3)), np.empty(3), np.empty(2)
    smooth = prior.shape[0] > 0
    A = np.empty((F * nv if smooth else 0, (prior.shape[1] - 1) * nv + 1))
    _view_arrays(R, t, sf, pinhole, D, M, T)
    _evaluate_all(q, tz, w, M, T, pinhole, sf, cxy, delta, model, Rp, pp, pos, res, cost)
    ang = np.empty((F if smooth else 0, nv))
    if smooth:
        _angles(q, q_of_v, pair, ang)
    total = cost.sum() + (_prior_terms(prior, ang, free, gq[:0]) if smooth else 0.0)
    total_t, lam, converged, it = 0.0, 1e-4, False, 0
    for it in range(1, max_iter + 1):
        _shared_blocks(w, M, T, R, t, sf, pinhole, fit_focal, fit_centre, delta, free, free_view, model, Rp, pp, pos,
                       res, Hqq, Hqc, gq, Hcc, gc)
        if smooth:
            _prior_terms(prior, ang, free, gq)
        stepped = False
        for _ in range(12):
            if smooth:
                _banded_step(Hqq, Hqc, gq, Hcc, gc, prior, lam, free, free_view, dq, dc, A, K)
            else:
                _schur_step(Hqq, Hqc, gq, Hcc, gc, lam, free, free_view, dq, dc, K)
            for r in range(F):
                _integrate(q[r], dq[r], free[r], q_of_v, pair, limited, lower, upper, q_t[r])
            sf_t = _moved_camera(dc, R, t, sf, cxy, pinhole, fit_focal, fit_centre, D, R_t, t_t, c_t)
            _view_arrays(R_t, t_t, sf_t, pinhole, D, M, T)
            _evaluate_all(q_t, tz, w, M, T, pinhole, sf_t, c_t, delta, model, Rp_t, pp_t, pos_t, res_t, cost_t)
            if smooth:
                _angles(q_t, q_of_v, pair, ang)
            total_t = cost_t.sum() + (_prior_terms(prior, ang, free, gq[:0]) if smooth else 0.0)
            if total_t <= total:
                stepped = True
                break
            lam *= 10
        if not stepped:  # no step lowers the cost any more: a minimum to machine precision
            converged = True
            break
        rel = (total - total_t) / max(total, 1e-300)
        q[:] = q_t
        R[:] = R_t
        t[:] = t_t
        cxy[:] = c_t
        sf = sf_t
        Rp, Rp_t, pp, pp_t = Rp_t, Rp, pp_t, pp  # the trial's placements, points and costs are now the fit's
        pos, pos_t, res, res_t, cost, cost_t = pos_t, pos, res_t, res, cost_t, cost
        total = total_t
        lam = max(lam / 5, 1e-12)
        if rel < tol or (total < 1e-24 if smooth else (cost < 1e-24).all()):
            converged = True
            break
    for r in range(F):
        for k in range(J):
            n2 = 0.0
            for i in range(D):
                n2 += res[r, k, i] * res[r, k, i]
            rn_out[r, k] = np.sqrt(n2)
            pos_out[r, k] = pos[r, k]
    return sf, it, converged


@_njit
def row_hashes(u, out):
    """A 64-bit multiplicative hash of each row of u (N, M) uint64 (a float array's bytes), into out (N,):
    :func:`chainspace.robot.solver._row_groups`' hash, column after column with wrapping arithmetic."""
    mult, shift = np.uint64(0x9E3779B97F4A7C15), np.uint64(29)
    for i in range(u.shape[0]):
        h = np.uint64(0)
        for j in range(u.shape[1]):
            h ^= u[i, j]
            h *= mult
            h ^= h >> shift
        out[i] = h


@_njit
def rows_match(k, lead):
    """Whether every row i of k (N, M) equals row lead[i] (as numbers: NaN equals nothing)."""
    for i in range(k.shape[0]):
        for j in range(k.shape[1]):
            if k[i, j] != k[lead[i], j]:
                return False
    return True


@_njit
def lex_order(k):
    """The order of the distinct rows of k (N, M) without NaN, lexicographic (column 0 first): what
    ``np.lexsort(k.T[::-1])`` gives them, by a merge sort that compares a row only as far as it must."""
    n = k.shape[0]
    order, spare = np.arange(n), np.empty(n, np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid, hi = min(lo + width, n), min(lo + 2 * width, n)
            a, b = lo, mid
            for o in range(lo, hi):
                take_a = b >= hi
                if a < mid and not take_a:
                    i, j = order[a], order[b]
                    c = 0
                    while c < k.shape[1] - 1 and k[i, c] == k[j, c]:
                        c += 1
                    take_a = k[i, c] <= k[j, c]
                if a < mid and take_a:
                    spare[o] = order[a]
                    a += 1
                else:
                    spare[o] = order[b]
                    b += 1
        order, spare = spare, order
        width *= 2
    return order


@_njit
def branch_steps(qs, turning, first, free_step, step, out):
    """The branch path's step costs from frame f - 1 to f, f = first, first + 1, ...: out[a, b, i] (K, K, n)
    for solution a of frame first + i - 1 to solution b of frame first + i, qs (K, F, nq), as
    ``candidates._branch_path`` writes them in numpy (the wrapped step's norm, its excess over
    free_step, over step, squared), the same numbers."""
    K, n, nq = qs.shape[0], out.shape[2], qs.shape[2]
    for i in range(n):
        f = first + i
        for a in range(K):
            for b in range(K):
                s2 = 0.0
                for j in range(nq):
                    d = qs[b, f, j] - qs[a, f - 1, j]
                    if turning[j]:
                        d = (d + np.pi) % (2 * np.pi) - np.pi
                    s2 += d * d
                x = max(np.sqrt(s2) - free_step, 0.0) / step
                out[a, b, i] = x * x


def threads() -> int:
    """Threads that :func:`run_rows` shares its rows among: ``CHAINSPACE_THREADS`` if set, else the cores
    this process may use (at most 8)."""
    env = os.environ.get("CHAINSPACE_THREADS", "").strip()
    if env:
        if not env.isdigit() or int(env) < 1:
            raise ChainspaceError(f"CHAINSPACE_THREADS must be a positive whole number of threads, not {env!r}")
        return int(env)
    return max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


_pools: dict[tuple[int, int], ThreadPoolExecutor] = {}  # by (process, threads): a forked child makes its own
MIN_ROWS_PER_THREAD = 256  # below it a thread's start costs more than its share of the rows


def _pool(pools: dict, n: int, name: str) -> ThreadPoolExecutor:
    """The pool of ``n`` threads named ``name`` in ``pools``, made on first use (one per process: a forked
    child makes its own)."""
    key = (os.getpid(), n)
    return pools.get(key) or pools.setdefault(key, ThreadPoolExecutor(n, thread_name_prefix=name))


def run_rows(q, tz, w, M, T, pinhole, f, cxy, free, delta, tol, it_from, it_to, lam, active, last_it, rn, pos_out,
             kept, more, model):
    """:func:`lm_rows` with its rows shared among :func:`threads` threads (the compiled loop releases
    the GIL; rows are independent, so the numbers do not depend on the split)."""
    n = min(threads(), len(q) // MIN_ROWS_PER_THREAD)
    if n <= 1:
        lm_rows(q, tz, w, M, T, pinhole, f, cxy, free, delta, tol, it_from, it_to, lam, active, last_it, rn, pos_out,
                kept, more, model)
        return
    pool = _pool(_pools, n, "chainspace-lm")
    cuts = np.linspace(0, len(q), n + 1).astype(int)
    jobs = [pool.submit(lm_rows, *(x[a:b] for x in (q, tz, w, M, T)), pinhole, f, cxy, free[a:b], delta, tol,
                        it_from, it_to,
                        *(x[a:b] for x in (lam, active, last_it, rn, pos_out)), tuple(x[a:b] for x in kept), more,
                        model)
            for a, b in zip(cuts[:-1], cuts[1:])]
    for job in jobs:
        job.result()


_task_pools: dict[tuple[int, int], ThreadPoolExecutor] = {}
_TASK_THREAD = "chainspace-fit"


def imap_tasks(robot, fn: Callable, items, step: Callable[[int], None] | None = None) -> Iterator:
    """The results of ``fn(x)`` for each of ``items``, in order, the calls shared among :func:`threads` threads
    where ``robot``'s kinematics are compiled (:meth:`CompiledModel.of`: batched, no Pinocchio data shared
    among the calls); each call's numbers are what it gives alone. On one thread each call is made as its
    result is asked for, so a caller can tell the next call what the last ones found. ``step(i)``
    (progress) is called in this thread as call i is waited for.

    Why: the fits that a robot fit tries from several starts are independent, and each spends its time in
    the compiled solvers, which release the GIL; a sequence fit with its camera (:func:`lm_shared`) runs on
    one thread, so on two cores two such fits run at once (issue 19). A pool of its own: its calls wait on
    :func:`run_rows`'s pool, which must not be the pool they run in; a call that maps tasks itself maps
    them on its own thread (waiting on the pool it runs in could wait for ever)."""
    items = list(items)
    n = min(threads(), len(items))
    step = step or (lambda i: None)
    if n <= 1 or CompiledModel.of(robot) is None or threading.current_thread().name.startswith(_TASK_THREAD):
        for i, x in enumerate(items):
            step(i)
            yield fn(x)
        return
    pool = _pool(_task_pools, n, _TASK_THREAD)
    jobs = [pool.submit(fn, x) for x in items]
    for i, job in enumerate(jobs):
        step(i)
        yield job.result()


def map_tasks(robot, fn: Callable, items, step: Callable[[int], None] | None = None) -> list:
    """``[fn(x) for x in items]`` as :func:`imap_tasks` makes them."""
    return list(imap_tasks(robot, fn, items, step))


@functools.cache
def _compiles() -> bool:
    """Whether the solver compiles here (once per process; numba's cache makes it quick after the first
    time): not without numba. Where numba is installed but cannot compile, the numpy solver is used and
    a warning says so."""
    if numba is None:
        return False
    try:
        compile_now()
    except Exception as exc:  # numba's errors come from many places (typing, LLVM, the cache's folder)
        warnings.warn(f"chainspace: the compiled robot solver could not be compiled here ({type(exc).__name__}: "
                      f"{exc}); the robot fit uses the slower numpy solver", RuntimeWarning, stacklevel=2)
        return False
    return True


def compile_now() -> None:
    """Compile the solver now, or load it from numba's cache: a benchmark that times fits then times the
    fits, not the one compilation after an install (some seconds). Runs one row of a one-joint arm, with
    the argument types of every fit's calls, through each compiled solver."""
    if numba is None:
        return
    i64 = np.int64
    model = (np.array([1], i64), np.array([0, 0], i64), np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 3)),
             np.array([FIXED, REVOLUTE], i64), np.array([[0.0, 0, 0], [0, 0, 1]]), np.zeros((2, 3, 3)),
             np.zeros((2, 3, 3)), np.zeros(2, i64), np.zeros(2, i64), np.ones(2), np.zeros(2), np.array([1], i64),
             np.array([[1.0, 0, 0]]), np.ones((1, 1), bool), np.zeros(1, bool), np.zeros(1), np.zeros(1),
             np.zeros(1, i64), np.zeros(1, i64), np.zeros(1, bool))
    lm_rows(np.zeros((1, 1)), np.zeros((1, 1, 2)), np.ones((1, 1)), np.zeros((1, 2, 3)), np.zeros((1, 2)), False,
            1.0, np.zeros(2), np.ones((1, 1), bool), -1.0, 1e-8, 1, 1, np.full(1, 1e-4), np.ones(1, bool),
            np.zeros(1, i64), np.zeros((1, 1)), np.zeros((1, 1, 3)),
            (np.zeros((1, 1, 1)), np.zeros((1, 1)), np.zeros(1), np.zeros(1, bool)), False, model)
    u = np.zeros((1, 1), np.uint64)
    row_hashes(u, np.zeros(1, np.uint64))
    rows_match(np.zeros((1, 1)), np.zeros(1, i64))
    lex_order(np.zeros((1, 1)))
    branch_steps(np.zeros((1, 2, 1)), np.zeros(1, bool), 1, 0.15, 0.1, np.zeros((1, 1, 1)))
    lm_shared(np.zeros((1, 1)), np.zeros((1, 1, 2)), np.ones((1, 1)), np.ones((1, 1), bool), np.ones(6, bool), -1.0,
              1e-8, 1, np.eye(3), np.zeros(3), 1.0, np.zeros(2), False, False, False, np.zeros((0, 3, 1)),
              np.zeros((1, 1)), np.zeros((1, 1, 3)), model)
