"""Levenberg-Marquardt over a sequence: per-frame joint angles and a shared (or per-frame) view,
a robust (Huber) loss, and the motion priors of the smoothed fit (on joint accelerations for the search,
on joint jerks for the answer).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .compiled import CompiledModel, _compiles, lm_shared, lex_order, row_hashes, rows_match, run_rows
from .kinematics import RobotKinematics
from .views import _PinholeView, _View


# Fewest rows for which the solver looks for rows that repeat or meet: below it (the sequential IK's
# blocks of 6 frames, solved a few hundred times a fit) the search cost more than the solves it saved
SHARED_ROWS_MIN = 16


def _huber(rn: np.ndarray, delta: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Huber loss rho(r) and IRLS weight rho'(r) / (2 r) of residual norms (plain squares when delta is None)."""
    if delta is None:
        return rn ** 2, np.ones_like(rn)
    inside = rn <= delta
    return (np.where(inside, rn ** 2, 2 * delta * rn - delta ** 2),
            np.where(inside, 1.0, delta / np.maximum(rn, 1e-300)))


def _normal_equations(view: _View, jac: np.ndarray, y: np.ndarray, res: np.ndarray, ww: np.ndarray,
                      free: np.ndarray, free_view: np.ndarray):
    """Gauss-Newton blocks of the weighted residuals res (F, J, D) = S (R x)[:D] + T - target.

    jac (F, J, 3, nv) point Jacobians, y = R x (F, J, 3), ww (F, J) IRLS weights. Returns per frame
    Hqq (F, nv, nv), Hqc (F, nv, nc), gq (F, nv) and per view Hcc (C, nc, nc), gc (C, nc); view
    parameters: those of the view's step (:meth:`_View.derivatives`, :meth:`_PinholeView.derivatives`).
    """
    F, J, D = res.shape
    if len(view.S) == 1 and isinstance(view, _View):
        # one view for every frame: d prediction / d point is one (D, 3) matrix, applied to all the
        # point Jacobians in a single product rather than one tiny product per point and frame
        M = view.S[0] * view.R[0, :D]  # the view's s R[:D] (view.matrices() makes it once per frame)
        # np.tensordot's own steps (the 3-axis first, one product) without its Python overhead
        Jq = np.dot(M, jac.transpose(2, 0, 1, 3).reshape(3, -1)).reshape(D, F, J, -1).transpose(1, 2, 0, 3)
    else:
        Jq = view.derivatives(y)[0] @ np.ascontiguousarray(jac)  # C-ordered: the layout BLAS was given
    # the mask only where a direction is held (a product by ones is the same numbers, at a cost), and
    # as floats: a bool operand made numpy cast it element by element
    Jq = (Jq if free.all() else Jq * free.astype(float)[:, None, None, :]).reshape(F, J * D, -1)
    # batched products over the stacked (point, axis) rows: einsum's three-operand loops were the
    # solver's main cost after the kinematics
    JqW = (Jq * np.repeat(ww, D, axis=1)[..., None]).transpose(0, 2, 1)
    r = res.reshape(F, J * D, 1)
    Hqq, gq = JqW @ Jq, (JqW @ r)[..., 0]
    if not free_view.any():  # the view held: its blocks are not needed
        return Hqq, None, gq, None, None
    Jc = (view.derivatives(y)[1] * free_view).reshape(F, J * D, -1)
    JcW = (Jc * np.repeat(ww, D, axis=1)[..., None]).transpose(0, 2, 1)
    Hqc = JqW @ Jc
    C, nc = len(view.S), view.n_params
    Hcc, gc = np.zeros((C, nc, nc)), np.zeros((C, nc))
    np.add.at(Hcc, view.cam_of, JcW @ Jc)
    np.add.at(gc, view.cam_of, (JcW @ r)[..., 0])
    return Hqq, Hqc, gq, Hcc, gc


def _row_groups(key: np.ndarray, ordered: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(first, inverse) of the equal rows of key (N, M), as ``np.unique(key, axis=0, return_index=True,
    return_inverse=True)[1:]`` gives them: the index of each distinct row's first occurrence, in
    lexicographic order of the rows (``ordered``; else in an order of no meaning), and each row's
    group.

    Why: np.unique sorts the rows as records, comparing field by field, which cost a branch search
    more than its linear algebra of small problems; here a 64-bit hash of each row's bytes is sorted
    instead, every row checked equal to its group's first (else np.unique decides), and only the
    distinct rows sorted lexicographically; the hash, the check and the sort in compiled code where it
    runs (in numpy they were 5-20 ms for a branch search's 7,800 rows). The same groups, the same order,
    the same bits after."""
    k = np.ascontiguousarray(key, dtype=float) + 0.0  # -0.0 -> 0.0: rows equal as numbers, equal as bytes
    u = k.view(np.uint64)
    h = np.zeros(len(k), np.uint64)
    compiled = _compiles()
    if compiled:
        row_hashes(u, h)
    else:
        mult, shift = np.uint64(0x9E3779B97F4A7C15), np.uint64(29)
        for j in range(k.shape[1]):  # a multiplicative hash, column after column (wrapping uint64 arithmetic)
            h ^= u[:, j]
            h *= mult
            h ^= h >> shift
    _, first, inverse = np.unique(h, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    same = rows_match(k, first[inverse]) if compiled else (k == k[first[inverse]]).all()
    if not same:  # a collision (or NaN): the record sort decides
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        return first, inverse.reshape(-1)
    if ordered:
        order = lex_order(k[first]) if compiled else np.lexsort(k[first].T[::-1])
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        first, inverse = first[order], rank[inverse]
    return first, inverse


def _beyond_sightings(unseen: np.ndarray) -> np.ndarray:
    """(F-1, nv) steps between frames f and f+1 that lie before the first or after the last frame in
    which each direction is seen (``unseen`` (F, nv): :func:`_unseen`); False for directions never seen."""
    seen = ~unseen
    F = len(seen)
    first = np.argmax(seen, axis=0)
    last = F - 1 - np.argmax(seen[::-1], axis=0)
    f = np.arange(F - 1)[:, None]
    return ((f >= last) | (f + 1 <= first)) & seen.any(0)


def _motion_prior(unseen: np.ndarray, mu: float, decay_frames: float):
    """(F nv, F nv) sparse matrix M of the prior on the motion, q' M q' (q' the joint angles frame after
    frame): mu |joint accelerations|^2 (per frame^2), plus, where a direction lies beyond its first or
    last sighting (``unseen`` (F, nv), :func:`_beyond_sightings`), mu / decay_frames^2 |joint speeds|^2
    (per frame).

    Why the second term: with nothing seen, the acceleration prior alone carries a joint on at its last
    speed for ever (a straight ramp costs nothing); with it, the speed decays with a time constant of
    ``decay_frames`` frames (inf: no decay) and the joint comes to rest."""
    import scipy.sparse as sp

    F, nv = unseen.shape
    L = _differences(F, 2)
    D1 = sp.kron(_differences(F, 1), sp.eye(nv))
    speed = sp.diags(_beyond_sightings(unseen).reshape(-1) * (mu / decay_frames ** 2))
    return (sp.kron(mu * (L.T @ L), sp.eye(nv)) + D1.T @ speed @ D1).tocsr()


# the jerk prior's frames of coupling (third differences); the acceleration prior couples two
MAX_PRIOR_FRAMES = 3
# beyond a joint's first or last sighting, under the jerk prior, its acceleration dies away with this time
# constant (s): the jerk prior alone would carry the last acceleration on for ever (a parabola costs no jerk)
ACCEL_DECAY_S = 0.25


def _differences(F: int, order: int):
    """(F - order, F) sparse matrix of the order-th differences of a sequence of F values."""
    import scipy.sparse as sp
    from math import comb

    return sp.diags([(-1.0) ** (order - k) * comb(order, k) * np.ones(F - order) for k in range(order + 1)],
                    list(range(order + 1)), shape=(F - order, F))


def _jerk_prior(unseen: np.ndarray, mu: float, decay_frames: float, accel_decay_frames: float = np.inf):
    """(F nv, F nv) sparse matrix M of the prior on joint jerks, q' M q' (q' the joint angles frame after
    frame): mu |joint jerks|^2 (third differences, per frame^3), plus, where a direction lies beyond its
    first or last sighting (``unseen`` (F, nv), :func:`_beyond_sightings`), mu (1 / ta^2 + 1 / tv^2)
    |joint accelerations|^2 + mu / (ta tv)^2 |joint speeds|^2 (ta = ``accel_decay_frames``, tv =
    ``decay_frames``; inf: that term off): there the speed is a exp(-t / ta) + b exp(-t / tv) + c (its
    acceleration dies away over ta frames, the speed over tv), with no overshoot. The jerk prior alone
    would carry a joint on at its last acceleration for ever (a parabola costs no jerk)."""
    import scipy.sparse as sp

    F, nv = unseen.shape
    if F <= 3:  # no third difference: nothing to penalise
        return sp.csr_matrix((F * nv, F * nv))
    beyond = _beyond_sightings(unseen)  # (F - 1, nv) steps
    D1, D2 = sp.kron(_differences(F, 1), sp.eye(nv)), sp.kron(_differences(F, 2), sp.eye(nv))
    speed = sp.diags(beyond.reshape(-1) * (mu / (accel_decay_frames * decay_frames) ** 2))
    accel = sp.diags((beyond[1:] & beyond[:-1]).reshape(-1) * (mu / accel_decay_frames ** 2 + mu / decay_frames ** 2))
    L = _differences(F, 3)
    return (sp.kron(mu * (L.T @ L), sp.eye(nv)) + D1.T @ speed @ D1 + D2.T @ accel @ D2).tocsr()


def _weight(sigma: float, std: float, fps: float, order: int) -> float:
    """The motion prior's weight mu per frame^order: an order-th derivative of ``std`` (rad/s^order, RMS)
    costs as much as pixel noise of ``sigma`` px at ``fps`` frames a second."""
    return sigma ** 2 / (float(std) / float(fps) ** order) ** 2


def _decay_frames(speed_decay_s: float | None, fps: float) -> float:
    """The speed decay beyond a joint's sightings in frames (inf: none)."""
    return np.inf if speed_decay_s is None else speed_decay_s * float(fps)


def acceleration_prior(unseen: np.ndarray, sigma: float, accel_std: float, fps: float,
                       speed_decay_s: float | None):
    """The acceleration prior of a fit (:func:`_motion_prior`): joint accelerations of ``accel_std``
    (rad/s^2, RMS) cost as much as pixel noise of ``sigma`` (px) at ``fps`` frames a second; beyond a
    joint's sightings its speed decays over ``speed_decay_s`` (None: never)."""
    return _motion_prior(unseen, _weight(sigma, accel_std, fps, 2), _decay_frames(speed_decay_s, fps))


def jerk_prior(unseen: np.ndarray, sigma: float, jerk_std: float, fps: float, speed_decay_s: float | None):
    """The jerk prior of a fit (:func:`_jerk_prior`): joint jerks of ``jerk_std`` (rad/s^3, RMS) cost as
    much as pixel noise of ``sigma`` (px) at ``fps`` frames a second; beyond a joint's sightings its
    acceleration dies away over :data:`ACCEL_DECAY_S` and its speed over ``speed_decay_s`` (None: never).

    Why a second prior: the acceleration prior (:func:`_motion_prior`) pulls a joint that the tracks fix
    poorly (near a singularity, at the ends of a sequence) towards rest. It is the stiffer model for the
    search for the right motion, this the better one for its final values
    (:func:`chainspace.robot.selection.under_jerk_prior`)."""
    return _jerk_prior(unseen, _weight(sigma, jerk_std, fps, 3), _decay_frames(speed_decay_s, fps),
                       ACCEL_DECAY_S * float(fps))


def prior_conflict(angles: np.ndarray, fps: float | None, accel_std: float | None,
                   jerk_std: float | None) -> tuple[float, tuple[float, float]]:
    """How far a fitted motion, ``angles`` (F, nv; rad, m for prismatic joints) at ``fps``, exceeds the
    motion priors it was fitted under: the largest ratio of a joint's RMS acceleration (over the frames)
    to ``accel_std`` and of its RMS jerk to ``jerk_std`` (a prior that is None counts 0); and those
    largest RMS rates (rad/s^2, rad/s^3). A fit pulled by its prior moves slower than the motion, so a
    ratio of several means the prior, not the tracks, set the answer's pace."""
    rates, ratio = [], 0.0
    for order, std in ((2, accel_std), (3, jerk_std)):
        d = np.diff(np.asarray(angles, float), order, axis=0) * float(fps or 0.0) ** order
        rate = float(np.sqrt((d ** 2).mean(0)).max()) if d.size else 0.0
        rates.append(rate)
        ratio = max(ratio, rate / std if std else 0.0)
    return ratio, (rates[0], rates[1])


def _smoothed_objective(prior, q: np.ndarray, rn: np.ndarray, w: np.ndarray, delta: float | None) -> float:
    """What :func:`_smooth_lm` minimises: robust residuals (norms rn (F, J), weights w, Huber threshold
    delta) plus the motion prior q' prior q' (q: the angles (F, nv), :meth:`RobotKinematics.angles`)."""
    qf = q.reshape(-1)
    return float((w * _huber(rn, delta)[0]).sum()) + float(qf @ (prior @ qf))


def prior_frames(prior, nv: int) -> int:
    """How many frames on the motion prior (a sparse (F nv, F nv) matrix, :func:`_motion_prior` or
    :func:`jerk_prior`) couples a joint to itself: 2 for the acceleration prior, 3 for the jerk prior."""
    F = prior.shape[0] // max(nv, 1)
    return max([s for s in range(1, min(MAX_PRIOR_FRAMES, F - 1) + 1) if prior.diagonal(s * nv).any()], default=1)


def _prior_band(prior, F: int, nv: int) -> np.ndarray | None:
    """The motion prior (:func:`_motion_prior`, :func:`jerk_prior`) as the compiled solver takes it:
    P (F, S + 1, nv) (S = :func:`prior_frames`), P[f, s, a] the entry that couples joint a at frame f to
    itself at frame f + s; None if it has other entries."""
    S = prior_frames(prior, nv)
    P = np.zeros((F, S + 1, nv))
    kept = 0
    for s in range(min(S + 1, F)):
        d = prior.diagonal(s * nv)
        P[:F - s, s] = d.reshape(F - s, nv)
        kept += np.count_nonzero(d) * (2 if s else 1)  # the matrix is symmetric: the lower side counts too
    return P if kept == np.count_nonzero(prior.data if hasattr(prior, "data") else prior) else None


def _smooth_lm(robot: RobotKinematics, q: np.ndarray, target: np.ndarray, w: np.ndarray, view: _View,
               free: np.ndarray, free_view: np.ndarray, max_iter: int, tol: float, delta: float | None,
               prior):
    """Levenberg-Marquardt of :func:`_sequence_lm` for one shared view, plus a quadratic prior on the
    motion, q' prior q' with q' the (F nv,) joint angles frame after frame (:func:`_motion_prior`),
    that couples neighbouring frames.

    The joint-angle block of the normal equations is then banded (two frames either side); it is
    factored as a banded Cholesky (scipy.linalg.cholesky_banded) and the view eliminated by a
    Schur complement, so an iteration stays linear in the number of frames. Same returns. In compiled
    code (:func:`chainspace.robot.compiled.lm_shared`, the same steps) where it covers the robot and view.
    """
    from scipy.linalg import cho_solve_banded, cholesky_banded

    F, J, D = target.shape
    nv, nc = robot.nv, view.n_params
    tz = np.nan_to_num(target)
    model = CompiledModel.of(robot) if type(view) in (_View, _PinholeView) else None
    band = _prior_band(prior, F, nv) if model is not None and len(view.S) == 1 and not view.per_frame else None
    if band is not None:
        return _shared_view_rows(model, q, tz, w, view, free, free_view, max_iter, tol, delta, band)
    N = F * nv
    u = (prior_frames(prior, nv) + 1) * nv - 1  # upper bandwidth: frame f couples to f + S
    frozen = (~free).reshape(-1)
    prior_band = np.zeros((u + 1, N))
    for d in range(u + 1):  # upper diagonals of the prior, in the banded layout
        prior_band[u - d, d:] = prior.diagonal(d)

    def band(Hqq, extra):
        ab = prior_band.copy()
        for a_ in range(nv):  # block diagonal: (f nv + a, f nv + b) for b >= a
            for b_ in range(a_, nv):
                ab[u - (b_ - a_), np.arange(F) * nv + b_] += Hqq[:, a_, b_]
        ab[u] += extra
        return ab

    def evaluate(q, view):
        placed = robot.placed(q)  # the Jacobians only of the step taken (at the next iteration)
        pred, y = view.apply(placed.pos)
        res = pred - tz
        return placed, y, res, _smoothed_objective(prior, robot.angles(q), np.linalg.norm(res, axis=-1), w, delta)

    placed, y, res, cost = evaluate(q, view)
    lam, converged, it = 1e-4, False, 0
    for it in range(1, max_iter + 1):
        jac = robot.jacobians_of(placed)
        ww = w * _huber(np.linalg.norm(res, axis=-1), delta)[1]
        Hqq, Hqc, gq, Hcc, gc = _normal_equations(view, jac, y, res, ww, free, free_view)
        gq = gq.reshape(-1) + prior @ robot.angles(q).reshape(-1)  # angles (F, nv): q itself without continuous joints
        gq[frozen] = 0.0
        Hx = Hqc.reshape(N, nc)
        diag_q = np.einsum("fvv->fv", Hqq).reshape(-1) + prior.diagonal()
        for _ in range(12):
            ab = band(Hqq, lam * (diag_q + 1e-9 * diag_q.mean()) + frozen * 1e12)
            sol = cho_solve_banded((cholesky_banded(ab, check_finite=False), False), np.column_stack([gq, Hx]),
                                   check_finite=False)
            Hc = Hcc[0] + np.diag(lam * (np.diag(Hcc[0]) + 1e-12) + (~free_view) * 1.0)
            dc = -np.linalg.solve(Hc - Hx.T @ sol[:, 1:], gc[0] - Hx.T @ sol[:, 0]) * free_view
            dq = (-(sol[:, 0] + sol[:, 1:] @ dc)).reshape(F, nv) * free
            q_t, v_t = robot.integrate(q, dq), view.moved(dc[None])
            trial = evaluate(q_t, v_t)
            if trial[-1] <= cost:
                break
            lam *= 10
        else:
            converged = True
            break
        rel = (cost - trial[-1]) / max(cost, 1e-300)
        q, view = q_t, v_t
        placed, y, res, cost = trial
        lam = max(lam / 5, 1e-12)
        if rel < tol or cost < 1e-24:
            converged = True
            break
    return q, view, np.linalg.norm(res, axis=-1), placed.pos, np.full(F, converged), it


def _sequence_lm(robot: RobotKinematics, q: np.ndarray, target: np.ndarray, w: np.ndarray, view: _View,
                 free: np.ndarray, free_view: np.ndarray, max_iter: int, tol: float, delta: float | None):
    """Levenberg-Marquardt on all frames' joint angles and the view(s) against target (F, J, D).

    The normal equations have one (nv x nv) block per frame and one small block per view; the views are
    eliminated by a Schur complement (batched over frames), so an iteration costs one Pinocchio Jacobian
    pass and small batched solves. When the frames are independent (the view fixed, or one view per
    frame) each frame keeps its own damping and accepts its own steps, and converged frames drop out.
    free (F, nv) / free_view (3 + 1 + D,) mask the directions allowed to move; a robust Huber loss
    (IRLS) with threshold delta (None: squares). Returns (q, view, residual norms (F, J), base-frame
    positions (F, J, 3), converged (F,), iterations). With the view held, the rows are solved in
    compiled code where it covers the robot and view (:mod:`chainspace.robot.compiled`): the same steps.
    """
    F, J, D = target.shape
    nv, nc = robot.nv, view.n_params
    tz = np.nan_to_num(target)
    if not free_view.any() and len(view.S) == 1 and F >= SHARED_ROWS_MIN:
        # the frames are independent problems: rows that repeat one (same start, target, weights and
        # free directions; a branch search starts several ways that often meet) are solved once
        key = np.concatenate([np.round(q, 9), tz.reshape(F, -1), w, free], 1)
        first, inverse = _row_groups(key, ordered=False)
        if len(first) < 0.95 * F:
            first, inverse = _row_groups(key)  # np.unique's order: the rows as the solves saw them
            q1, _, rn1, pos1, conv1, it1 = _sequence_lm(robot, q[first], target[first], w[first], view.take(first),
                                                        free[first], free_view, max_iter, tol, delta)
            return q1[inverse], view, rn1[inverse], pos1[inverse], conv1[inverse], it1
        problem = _row_groups(key[:, q.shape[1]:], ordered=False)[1]
    else:
        problem = None
    model = CompiledModel.of(robot) if type(view) in (_View, _PinholeView) else None
    if model is not None and not free_view.any():
        return _independent_rows(model, q, tz, w, view, free, max_iter, tol, delta, problem)
    if model is not None and len(view.S) == 1 and not view.per_frame:
        return _shared_view_rows(model, q, tz, w, view, free, free_view, max_iter, tol, delta)
    follow = np.arange(F)  # a row that met another row of the same problem follows it from there on
    eye_q, eye_c = np.eye(nv), np.eye(nc)
    fixed_q, fixed_c = (~free).astype(float), (~free_view).astype(float)
    independent = not free_view.any() or view.per_frame
    q = q.copy()

    def evaluate(qa, va, a):
        placed = robot.placed(qa)  # the Jacobians only of the rows that step on (below)
        pred, y = va.apply(placed.pos)
        res = pred - tz[a]
        return placed, y, res, (w[a] * _huber(np.linalg.norm(res, axis=-1), delta)[0]).sum(1)

    placed, y, res, cost = evaluate(q, view, np.arange(F))
    pos, jac = placed.pos, robot.jacobians_of(placed)
    lam = np.full(F, 1e-4)
    active = np.ones(F, bool)
    held_view = not free_view.any()
    if held_view:
        # the view held: each row's normal equations depend on its own q alone, so a row whose last step
        # was rejected (about a third of a branch search's rows late in its run) keeps them, unchanged
        Hqq_all, gq_all, stale = np.empty((F, nv, nv)), np.empty((F, nv)), np.ones(F, bool)
    it = 0
    for it in range(1, max_iter + 1):
        a = np.flatnonzero(active)
        va = view.take(a)
        if held_view:
            s = a[stale[a]]
            if len(s):
                ww = w[s] * _huber(np.linalg.norm(res[s], axis=-1), delta)[1]
                Hqq_all[s], _, gq_all[s], _, _ = _normal_equations(view.take(s), jac[s], y[s], res[s], ww, free[s],
                                                                   free_view)
                stale[s] = False
            Hqq, Hqc, gq, Hcc, gc = Hqq_all[a], None, gq_all[a], None, None
        else:
            ww = w[a] * _huber(np.linalg.norm(res[a], axis=-1), delta)[1]
            Hqq, Hqc, gq, Hcc, gc = _normal_equations(va, jac[a], y[a], res[a], ww, free[a], free_view)
        Ca = len(va.S)
        dq_diag = np.einsum("fvv->fv", Hqq)
        floor_q = 1e-6 * dq_diag.mean(1, keepdims=True) + 1e-30
        for _ in range(1 if independent else 12):
            la = lam[a]
            Hq = Hqq + (la[:, None] * (dq_diag + floor_q) + fixed_q[a])[:, :, None] * eye_q
            if Hcc is None:  # the view held: frame by frame, no view step
                dq = -np.linalg.solve(Hq, gq[..., None])[..., 0] * free[a]
                q_t, v_t = robot.integrate(q[a], dq), va
                pl_t, y_t, r_t, c_t = evaluate(q_t, v_t, a)
                better = c_t <= cost[a]
                break
            dc_diag = np.einsum("cdd->cd", Hcc)
            lc = la if Ca == len(a) else la[:1]
            Hc = Hcc + (lc[:, None] * (dc_diag + 1e-12) + fixed_c)[:, :, None] * eye_c
            Hq_inv = np.linalg.inv(Hq)
            K = Hq_inv @ Hqc  # (F, nv, nc)
            schur, rhs = Hc.copy(), gc.copy()
            np.add.at(schur, va.cam_of, -np.einsum("fvc,fvd->fcd", Hqc, K))
            np.add.at(rhs, va.cam_of, -np.einsum("fvc,fv->fc", K, gq))
            dc = -np.linalg.solve(schur, rhs[..., None])[..., 0] * free_view
            dq = -(np.einsum("fvu,fu->fv", Hq_inv, gq) + np.einsum("fvc,fc->fv", K, dc[va.cam_of])) * free[a]
            q_t, v_t = robot.integrate(q[a], dq), va.moved(dc)
            pl_t, y_t, r_t, c_t = evaluate(q_t, v_t, a)
            better = c_t <= cost[a] if independent else np.full(len(a), c_t.sum() <= cost[a].sum())
            if better.any():
                break
            lam[a] *= 10
        if not better.any() and not independent:
            active[:] = False  # no step lowers the cost any more: a minimum to machine precision
            break
        b = a[better]
        rel = (cost[b] - c_t[better]) / np.maximum(cost[b], 1e-300)
        if not independent:
            rel = np.full(len(b), (cost[b].sum() - c_t.sum()) / max(cost[b].sum(), 1e-300))
        q[b], pos[b], y[b], res[b], cost[b] = q_t[better], pl_t.pos[better], y_t[better], r_t[better], c_t[better]
        view = view.put(a, v_t, better)
        if held_view:
            stale[b] = True
        lam[b] = np.maximum(lam[b] / 5, 1e-12)
        lam[a[~better]] *= 10
        done = (rel < tol) | (cost[b] < 1e-24)
        if independent:
            active[b[done]] = False
            active[a[~better][lam[a[~better]] > 1e10]] = False
        elif done.all():
            active[:] = False
        if problem is not None and it in MERGE_AT:
            _merge_met(problem, q, active, follow)
        on = better & active[a]  # rows that took a step and go on: their Jacobians at the new q
        if on.any():
            jac[a[on]] = robot.jacobians_of(pl_t, slice(None) if on.all() else np.flatnonzero(on))
        if not active.any():
            break
    if problem is not None:
        while not np.array_equal(follow[follow], follow):
            follow = follow[follow]
        return q[follow], view, np.linalg.norm(res, axis=-1)[follow], pos[follow], (~active)[follow], it
    return q, view, np.linalg.norm(res, axis=-1), pos, ~active, it


# iterations after which starts of one problem that have met go on as one (_sequence_lm, _independent_rows)
MERGE_AT = (3, 6, 10, 15, 21)


def _merge_met(problem: np.ndarray, q: np.ndarray, active: np.ndarray, follow: np.ndarray) -> None:
    """Starts of one problem that have met (within a micro-radian) go on as one, in place: a branch
    search's many starts fall into a few basins. The first of each group leads, the others follow it
    (``follow``) and stop (``active``)."""
    live = np.flatnonzero(active)
    first, inv = _row_groups(np.column_stack([problem[live], np.round(q[live], 6)]), ordered=False)
    lead = live[first][inv]
    follow[live] = lead
    active[live[lead != live]] = False


def _independent_rows(model: CompiledModel, q: np.ndarray, tz: np.ndarray, w: np.ndarray, view: _View,
                      free: np.ndarray, max_iter: int, tol: float, delta: float | None,
                      problem: np.ndarray | None):
    """:func:`_sequence_lm` with the view held, its rows independent, in compiled code
    (:func:`chainspace.robot.compiled.lm_rows`) between the iterations at which met starts merge. Same
    returns."""
    F, J, D = tz.shape
    q = np.array(q, dtype=float, order="C")
    pinhole = isinstance(view, _PinholeView)
    if pinhole:
        M, T = (np.ascontiguousarray(np.broadcast_to(a[0], (F,) + a.shape[1:])) for a in (view.R, view.t))
        f, cxy = float(view.f), np.ascontiguousarray(view.c, dtype=float)  # one compiled signature (c may be a view)
    else:
        M, T = np.ascontiguousarray(view.matrices()), np.ascontiguousarray(view.T[view.cam_of])
        f, cxy = 1.0, np.zeros(2)
    lam, active = np.full(F, 1e-4), np.ones(F, bool)
    last, rn, pos = np.zeros(F, np.int64), np.empty((F, J)), np.empty((F, J, 3))
    nv = free.shape[1]
    kept = (np.empty((F, nv, nv)), np.empty((F, nv)), np.empty(F), np.zeros(F, bool))  # see lm_rows
    follow = np.arange(F)
    tz, w, free = (np.ascontiguousarray(a, dtype=t) for a, t in ((tz, float), (w, float), (free, bool)))
    start = 1
    for stop in [m for m in MERGE_AT if m < max_iter] + [max_iter]:
        run_rows(q, tz, w, M, T, pinhole, f, cxy, free, -1.0 if delta is None else float(delta), float(tol), start,
                 stop, lam, active, last, rn, pos, kept, stop < max_iter, model.args())
        if not active.any():
            break
        if problem is not None and stop in MERGE_AT:
            was = active.copy()
            _merge_met(problem, q, active, follow)
            last[was & ~active] = stop  # the rows that now follow another stopped here
        start = stop + 1
    it = max_iter if active.any() else int(last.max())
    while not np.array_equal(follow[follow], follow):
        follow = follow[follow]
    return q[follow], view, rn[follow], pos[follow], (~active)[follow], it


def _shared_view_rows(model: CompiledModel, q: np.ndarray, tz: np.ndarray, w: np.ndarray, view: _View,
                      free: np.ndarray, free_view: np.ndarray, max_iter: int, tol: float, delta: float | None,
                      prior: np.ndarray | None = None):
    """:func:`_sequence_lm` with one view shared by every frame and free to move, in compiled code
    (:func:`chainspace.robot.compiled.lm_shared`: the same steps); with ``prior`` (:func:`_prior_band`)
    :func:`_smooth_lm`'s. Same returns."""
    F, J, D = tz.shape
    q = np.array(q, dtype=float, order="C")
    pinhole = isinstance(view, _PinholeView)
    R, t, c = np.array(view.R[0], dtype=float), np.zeros(3), np.zeros(2)
    if pinhole:
        t[:], c[:], sf, fit_focal, fit_centre = view.t[0], view.c, float(view.f), view.fit_focal, view.fit_centre
    else:
        t[:D], sf, fit_focal, fit_centre = view.T[0], float(view.S[0]), False, False
    rn, pos = np.empty((F, J)), np.empty((F, J, 3))
    tz, w, free = (np.ascontiguousarray(a, dtype=k) for a, k in ((tz, float), (w, float), (free, bool)))
    sf, it, converged = lm_shared(q, tz, w, free, np.ascontiguousarray(free_view, dtype=bool),
                                  -1.0 if delta is None else float(delta), float(tol), int(max_iter), R, t, sf, c,
                                  pinhole, bool(fit_focal), bool(fit_centre),
                                  np.zeros((0, 3, free.shape[1])) if prior is None else prior, rn, pos, model.args())
    if pinhole:
        view = replace(view, R=R[None], t=t[None], f=float(sf), c=c)
    else:
        view = _View(np.array([sf]), R[None], t[None, :D], view.cam_of)
    return q, view, rn, pos, np.full(F, converged), int(it)


def _rms_per_frame(rn: np.ndarray, w: np.ndarray) -> np.ndarray:
    wf = w.sum(1)
    return np.where(wf > 0, np.sqrt((w * rn ** 2).sum(1) / np.maximum(wf, 1e-300)), np.nan)


def _noise_sigma(rn: np.ndarray, w: np.ndarray) -> float:
    """Pixel noise (per coordinate) from 2D residual norms rn (F, J): the median norm of the used
    points over 1.1774, the median of a 2D Gaussian's norm in units of sigma; 0 when none is used."""
    r = rn[w > 0]
    return float(np.median(r)) / 1.1774 if r.size else 0.0


def _robust_scale(rn: np.ndarray, w: np.ndarray, floor: float) -> float:
    """Huber threshold: 3 robust standard deviations of the used residual norms."""
    r = rn[w > 0]
    return max(3.0 * 1.4826 * float(np.median(r)) if r.size else 0.0, floor)
