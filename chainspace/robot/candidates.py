"""The other motions that fit the tracks alike: depth flips of planar parts, IK branches chosen
by dynamic programming, branches after long gaps, views turned about the first joint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .compiled import _compiles, branch_steps
from .kinematics import RobotKinematics, _gauge_q, _held_q, _random_q, _relative_difference, _seeded, _wrapped
from .views import _PinholeView, _View, _camera_view, similarity_align
from .solver import _sequence_lm
from .observability import _hold, _moves

# The tie policy (one for every rule of chainspace.robot.fit; see "Ambiguities" there):
# * candidate: a fitted motion, a dict with at least ``q`` (F, nq) and its ``out`` of the solver;
# * tolerance: two candidates tie when their objectives (squared or robust residuals, plus the motion
#   prior when smoothed) differ by at most TIE_VARIANCES noise variances (a likelihood-ratio test);
# * de-duplication: two motions are one when no joint differs by more than DISTINCT_RAD in any frame (a
#   joint seen only relative to frame 0 compared as its change since frame 0, where the caller knows it);
# * distance to rest: kinematics._rest_distance (summed absolute wrapped offsets from the rest pose).
TIE_VARIANCES = 25.0
DISTINCT_RAD = 0.05


def _same_motion(robot: RobotKinematics, qa: np.ndarray, qb: np.ndarray, relative: np.ndarray | None = None) -> bool:
    """True when motions qa and qb (F, nq or nq) are one candidate: no entry differs by more than
    :data:`DISTINCT_RAD` (wrapped); the joints ``relative`` (nv,), seen only relative to frame 0, compared
    as their change since frame 0 (motions (F, nq) only): one offset in every frame is a turn of the camera.
    The Kinova from below (full ranges, pinhole, seed 30) listed its own motion with joint 1 a quarter turn
    off as another that fits as well."""
    if relative is None or not np.any(relative):
        return bool(np.abs(_wrapped(robot, np.asarray(qa) - np.asarray(qb))).max() < DISTINCT_RAD)
    return _motion_distance(robot, qa, qb, relative) < DISTINCT_RAD


def _motion_distance(robot: RobotKinematics, qa: np.ndarray, qb: np.ndarray, relative: np.ndarray) -> float:
    """The largest difference between motions qa and qb (F, nq) over frames and degrees of freedom (rad,
    wrapped; m for sliding joints), the joints ``relative`` (nv,) compared as their change since frame 0."""
    return float(np.abs(_relative_difference(robot, robot.angles(qa), robot.angles(qb), relative)).max())


def _viterbi_branches(robot: RobotKinematics, q: np.ndarray, target: np.ndarray, w: np.ndarray, view: _View,
                      free: np.ndarray, sigma: float, n_random: int = 4, step: float = 0.1, free_step: float = 0.15,
                      seed: int = 0) -> np.ndarray:
    """The sequence's branch, chosen globally: per frame a few IK solutions under the fixed view(s)
    (from the current path, the rest pose and random configurations, batched), then the path through
    them with the lowest total cost by dynamic programming (Viterbi), as the reconstruction chooses
    its depth signs.

    A wrong branch in some frames (an elbow or wrist mirrored where the projections tie) is a local
    minimum of the smooth sequence objective that no local step leaves; the choice here is global.
    Cost: squared residuals over sigma^2 (pixel noise, D-space units) per frame, plus for a joint step
    between consecutive frames longer than ``free_step`` (rad; 4.5 rad/s at 30 fps, more than robots
    move) the excess squared over ``step``^2, plus a whisker of distance to the rest pose that decides
    exact ties: a jump to another branch is costly, while of two continuous paths that fit alike
    (a wrist's planar tool mirrored in depth) the one nearer the rest pose wins. Returns q (F, nq).
    """
    rng = np.random.default_rng(seed)
    held_q = _held_q(robot, free)  # entries held in a frame keep their value in every start
    rand = _random_q(robot, rng, n_random)
    starts = [q, _seeded(robot, q, free), _seeded(robot, q, free, True)] + [np.where(held_q, q, r) for r in rand] + \
        [np.where(held_q, q, m) for m in _depth_flips(robot, q, view, free)]
    return _branch_path(robot, starts, target, w, view, free, sigma, step, free_step)


def _branch_path(robot: RobotKinematics, starts: list[np.ndarray], target: np.ndarray, w: np.ndarray, view: _View,
                 free: np.ndarray, sigma: float, step: float = 0.1, free_step: float = 0.15) -> np.ndarray:
    """The path (F, nq) of :func:`_viterbi_branches` through the per-frame solutions from ``starts``
    (each (F, nq)): every frame solved from every start, then the cheapest path by dynamic programming."""
    F, nq = starts[0].shape
    K = len(starts)
    q0 = np.concatenate(starts)
    idx = np.tile(np.arange(F), K)
    # stopped at a millionth's relative change: these solutions only rank the branches, and the path
    # picked is solved again as a sequence (issue 19: a tenth of a 6-axis arm's fit was rows creeping)
    qs, _, rn, _, _, _ = _sequence_lm(robot, q0, target[idx], w[idx], view.take(idx), free[idx],
                                      np.zeros(view.n_params, bool), 30, 1e-6, None)
    qs = qs.reshape(K, F, nq)
    data = (w[idx] * rn ** 2).sum(1).reshape(K, F) / max(sigma, 1e-12) ** 2
    data += 0.05 * np.abs(_wrapped(robot, qs - robot.q_rest)).sum(-1)
    back = np.zeros((F, K), int)
    acc = data[:, 0].copy()
    compiled = _compiles()
    qc = np.ascontiguousarray(qs)
    for f in range(1, F):  # a loop over frames: the recursion is sequential, each step is (K, K)
        if (f - 1) % 128 == 0:  # the steps' costs of the next frames at once (one pass, not 128)
            b = slice(f, min(f + 128, F))
            if compiled:  # the same numbers, without the (K, K, 128, nq) temporaries
                trans_block = np.empty((K, K, b.stop - b.start))
                branch_steps(qc, robot.revolute, b.start, free_step, step, trans_block)
            else:
                jump = np.linalg.norm(_wrapped(robot, qs[None, :, b] - qs[:, None, b.start - 1:b.stop - 1]), axis=-1)
                trans_block = (np.maximum(jump - free_step, 0.0) / step) ** 2  # (from, to, frame)
        tot = acc[:, None] + trans_block[:, :, (f - 1) % 128]
        back[f] = np.argmin(tot, 0)
        acc = tot[back[f], np.arange(K)] + data[:, f]
    k = np.empty(F, int)
    k[-1] = int(np.argmin(acc))
    for f in range(F - 1, 0, -1):
        k[f - 1] = back[f, k[f]]
    return robot.continuous(qs[k, np.arange(F)])


_LONG_GAP = 21  # frames: half a turn at the branch search's free step (0.15 rad per frame)


def _held_runs(held: np.ndarray) -> np.ndarray:
    """(F, n) length of the run of held frames that ends at each frame (0 where not held)."""
    runs = np.zeros(held.shape, int)
    runs[0] = held[0]
    for f in range(1, len(held)):
        runs[f] = (runs[f - 1] + 1) * held[f]
    return runs


def _across_long_gaps(robot: RobotKinematics, q: np.ndarray, tracks: np.ndarray, w: np.ndarray, view: _View,
                      free: np.ndarray, sigma: float, min_gap: int, n_random: int = 24, seed: int = 0) -> list[np.ndarray]:
    """Starts that bridge each long gap to another branch: where a direction is seen again after
    ``min_gap`` or more frames unseen, the IK solutions of that frame (from random starts) that fit it
    within 25 noise variances of the best, each joined to the last sighting by a straight line over
    the gap. After such a gap the joint may come back on any branch, and the frame alone may fit a
    wrong one as well as the true one."""
    runs = _held_runs(~free)
    back = np.flatnonzero(((runs[:-1] >= min_gap) & free[1:]).any(1)) + 1  # frames seen again
    if not len(back):
        return []
    rng = np.random.default_rng(seed)
    starts = []
    for b in back[:4]:  # a few: each costs a batched IK of that frame and a smoothed fit per branch
        idx = np.full(n_random + 1, b)
        q0 = np.where(_held_q(robot, free[b]), q[b], np.vstack([q[b], _random_q(robot, rng, n_random)]))
        qs, _, rn, _, _, _ = _sequence_lm(robot, q0, tracks[idx], w[idx], view.take(idx), free[idx],
                                          np.zeros(view.n_params, bool), 30, 1e-8, None)
        sse = (w[b] * rn ** 2).sum(1)
        kept: list[np.ndarray] = []
        for k in np.argsort(sse):
            if sse[k] > sse.min() + TIE_VARIANCES * sigma ** 2:
                break
            if any(_same_motion(robot, qs[k], o) for o in kept + [q[b]]):
                continue
            kept.append(qs[k])
            bridged = robot.continuous(q.copy())
            bridged[b] = robot.wrap_near(qs[k][None], bridged[b - 1])[0]
            ang = robot.angles(bridged)  # (F, nv), unwrapped along the frames
            for v in np.flatnonzero(runs[b - 1] >= min_gap):
                a = b - runs[b - 1, v]
                if a > 0:
                    ang[a:b, v] = np.linspace(ang[a - 1, v], ang[b, v], b - a + 2)[1:-1]
                    moved = robot.q_mask(np.arange(robot.nv) == v)
                    bridged[a:b][:, moved] = robot.from_angles(ang[a:b])[:, moved]
            starts.append(bridged)
    return starts


def _viterbi_reanchored(robot: RobotKinematics, q: np.ndarray, tracks: np.ndarray, w: np.ndarray, view: _View,
                        free: np.ndarray, sigma: float, gauge: np.ndarray, per_frame: bool, blind: np.ndarray,
                        unseen: np.ndarray) -> tuple[np.ndarray, _View]:
    """:func:`_viterbi_branches` on the tracks with a static camera's gauge joint free in frame 0 too.

    The gauge joint (seen only relative to frame 0) is held at rest in frame 0, and the camera turned
    to match. If frame 0 started on a wrong branch, the camera was turned by that branch's error and
    no pose of frame 0 with the held value fits: the frame is stuck however the others move. Here
    frame 0 may take any value under the current camera; afterwards the whole sequence is shifted
    back to rest in frame 0 and the camera re-fitted (in closed form) to the shifted motion.
    Returns (q, view)."""
    if per_frame or not gauge.any():
        return _viterbi_branches(robot, q, tracks, w, view, free, sigma), view
    free0 = free.copy()
    free0[0] |= gauge & ~blind & ~unseen[0]
    q_fix = _viterbi_branches(robot, q, tracks, w, view, free0, sigma)
    if np.abs(_wrapped(robot, q_fix[0] - q[0])[_gauge_q(robot, gauge)]).max(initial=0.0) < 1e-9:
        return q_fix, view
    q_fix, _ = _hold(robot, q_fix, blind, gauge, False)
    if not isinstance(view, _View):  # a pinhole camera: re-fitted by Levenberg-Marquardt, the motion held
        out = _sequence_lm(robot, q_fix, tracks, w, view, np.zeros_like(free), np.ones(view.n_params, bool), 30,
                           1e-10, None)
        return q_fix, out[1]
    return q_fix, _camera_view(robot.positions(q_fix), tracks, w, False)


def _mirrored_beyond(pos: np.ndarray, beyond: np.ndarray, centre: int, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points pos (F, J, 3) with those marked ``beyond`` (J,) mirrored in depth (the unit axis n (F, 3))
    about the plane through point ``centre``, facing the camera; and their depths (F, n) before."""
    depth = np.einsum("fjd,fd->fj", pos[:, beyond] - pos[:, centre, None], n)
    out = pos.copy()
    out[:, beyond] -= 2 * depth[..., None] * n[:, None]
    return out, depth


def _depth_flips(robot: RobotKinematics, q: np.ndarray, view: _View, free: np.ndarray) -> list[np.ndarray]:
    """Starts on the other side of each link's depth ambiguity: per tree link, the configuration whose
    points best match the current ones with that link and everything beyond it mirrored in depth
    (about the plane through the link's parent point, facing the camera). A weak-perspective camera
    sees both alike; the arm beyond a ball-like joint (a 7-axis arm's shoulder, a wrist) can often
    take the mirrored pose exactly. Random starts rarely land in that basin. (F, nq) each."""
    F = len(q)
    pos = robot.positions(q)
    mirrored = _mirror_targets(robot, pos, view)
    # also the same points reached with the joints from each one on started from either side of the
    # rest pose: the other branches that put every point where it is (a wrist turned half a turn with
    # the next joint mirrored)
    partial = []
    for k in np.flatnonzero(robot.revolute):
        for other_side in (False, True):
            start = q.copy()
            start[:, k:] = _seeded(robot, q, free, other_side)[:, k:]
            partial.append(start)
    targets = [pos] * len(partial) + mirrored
    starts = partial + [q] * len(mirrored)
    K = len(targets)
    eye = _View.identity(K * F)
    # under a weak camera 15 iterations, not 30: these are starts, solved again on the tracks (_branch_path);
    # the rows still moving after 15 creep in basins that leave their targets far (a third of them, the
    # milling arm), and their last 15 iterations were a tenth of its fit (issue 19; docs/benchmarks.md, Robot
    # fit speed, stop 50). Under a pinhole camera (the perspective fit's own branch choice) 30: cut there too,
    # the Solo12 from above (full ranges, seed 45) ended with a leg 5-34 degrees off, reported observable
    iters = 30 if isinstance(view, _PinholeView) else 15
    qs = _sequence_lm(robot, np.concatenate(starts), np.concatenate(targets), np.ones((K * F, pos.shape[1])), eye,
                      np.tile(free, (K, 1)), np.zeros(7, bool), iters, 1e-8, None)[0]
    return list(qs.reshape(K, F, -1))


def _mirror_targets(robot: RobotKinematics, pos: np.ndarray, view: _View) -> list[np.ndarray]:
    """Per tree link that is not already in the plane facing the camera: the points pos (F, J, 3) with
    that link and everything beyond it mirrored in depth about its parent point (the view's depth axis)."""
    n = view.R[view.cam_of][:, 2]  # (F, 3) the camera's depth axis in the base frame
    index = {name: i for i, name in enumerate(robot.chain.joints)}
    mirrored = []
    for b, (parent, _) in enumerate(robot.chain.bones):
        m, depth = _mirrored_beyond(pos, robot.chain.D[b] != 0, index[parent], n)
        if np.abs(depth).max() >= 1e-9:
            mirrored.append(m)
    return mirrored


def _far_depth_flips(robot: RobotKinematics, q: np.ndarray, view: _View, free: np.ndarray) -> list[np.ndarray]:
    """The depth flips of :func:`_depth_flips` that are poses of the robot far from q (F, nq) in joint
    space (:func:`_far_poses`). Why: the arm beyond a 7-axis arm's shoulder mirrored in depth is again
    a pose of the arm, but one that turns the first, third, fifth and seventh joints by up to half a
    turn, out of reach of IK started from q. Through a weak camera over the Panda's full ranges (seed
    22 from above) the truth was that mirror, its objective 27 noise variances below the reported
    motion's, and no candidate reached it."""
    return _far_poses(robot, q, _mirror_targets(robot, robot.positions(q), view), free)


def _branches_combined(robot: RobotKinematics, qs: np.ndarray, rn: np.ndarray, n_frames: int, target: np.ndarray,
                       w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IK solutions ``qs`` (n_frames * n_starts, nq, frame by frame) and their residuals ``rn`` (same rows,
    J), with one more row per frame (the last of its rows): for each branch of the tree (joints moving
    points no other branch moves: a quadruped's legs), the joints of the start that put that branch's
    points nearest ``target`` (n_frames, J, 3; weights ``w``). Why: one start must reach every leg at
    once, which few random starts do for four legs half a turn from them (Solo12's mirror image: each
    leg reached by about half the starts, all four by one or none in some frames)."""
    moves = _moves(robot)  # (J, nv)
    groups = _branch_groups(moves)
    if len(groups) < 2:
        return qs, rn
    a = robot.angles(qs).reshape(n_frames, -1, robot.nv)
    r = rn.reshape(n_frames, -1, rn.shape[-1])
    combined = a[:, 0].copy()
    for joints in groups:
        best = r[:, :, moves[:, joints].any(1)].max(2).argmin(1)  # (n_frames,) the start nearest on this branch
        combined[:, joints] = a[np.arange(n_frames), best][:, joints]
    qc = robot.from_angles(combined)
    rc = np.linalg.norm(robot.positions(qc) - target, axis=-1) * (w > 0)
    qs = np.concatenate([qs.reshape(n_frames, -1, qs.shape[-1]), qc[:, None]], 1).reshape(-1, qs.shape[-1])
    rn = np.concatenate([r, rc[:, None]], 1).reshape(-1, rn.shape[-1])
    return qs, rn


def _branch_groups(moves: np.ndarray) -> list[np.ndarray]:
    """The joints (nv) split into branches: two joints are in one branch when they move a common point
    (``moves`` (J, nv)), directly or through others; joints that move no point are in none."""
    from scipy.sparse.csgraph import connected_components

    linked = (moves.T.astype(int) @ moves.astype(int)) > 0  # (nv, nv) share a point
    label = connected_components(linked, directed=False)[1]
    return [np.flatnonzero(label == k) for k in np.unique(label[moves.any(0)])]


def _far_poses(robot: RobotKinematics, q: np.ndarray, targets: list[np.ndarray], free: np.ndarray,
               n_samples: int = 5, n_random: int = 24, seed: int = 0) -> list[np.ndarray]:
    """Per target (F, J, 3) of tracked points in the base frame, the motion (F, nq) that puts every
    point there (to a thousandth of the robot's reach), wherever it lies in joint space: IK on a few
    frames from q (F, nq), the two seeds and random configurations; where some start reaches the
    target in each of those frames, the continuous path through every frame from their solutions
    (:func:`_branch_path`). Joints free in any frame (``free`` (F, nv)) move in every frame: one held
    in frame 0 only (seen relative to it) may need the camera's turn. Targets no motion reaches give
    nothing."""
    F = len(q)
    tol = 1e-3 * robot.reach()
    movable = np.repeat(free.any(0, keepdims=True), F, 0)
    samples = np.unique(np.linspace(0, F - 1, min(n_samples, F)).round().astype(int))
    pool = np.vstack([robot.q_seed, robot.q_seed_other, _random_q(robot, np.random.default_rng(seed), n_random)])
    starts = np.concatenate([np.vstack([q[f], pool]) for f in samples])
    rows = np.repeat(samples, len(pool) + 1)
    out = []
    for m in targets:
        ones = np.ones(m.shape[:2])
        qs, _, rn, _, _, _ = _sequence_lm(robot, starts, m[rows], ones[rows], _View.identity(len(rows)),
                                          movable[rows], np.zeros(7, bool), 40, 1e-10, None)
        qs, rn = _branches_combined(robot, qs, rn, len(samples), m[samples], ones[samples])
        hit = rn.max(1) < tol
        if not hit.reshape(len(samples), -1).any(1).all():
            continue  # not a pose of the robot in some frame
        found: list[np.ndarray] = []
        for s in qs[hit]:
            if not any(_same_motion(robot, s, o) for o in found):
                found.append(s)
        path = _branch_path(robot, [np.tile(s, (F, 1)) for s in found], m, ones, _View.identity(F), movable, 0.1 * tol)
        # solved again to the end: the path search stops early, and a pose is scored as it is
        path, _, rn, _, _, _ = _sequence_lm(robot, path, m, ones, _View.identity(F), movable, np.zeros(7, bool), 30,
                                            1e-10, None)
        if rn.max() < tol:
            out.append(path)
    return out


FACE_ON_DEG = 15.0  # a plane within this angle of face-on is reported as seen face-on


def _face_on_planes(robot: RobotKinematics, q: np.ndarray, depth: np.ndarray,
                    max_angle: float = np.radians(FACE_ON_DEG)) -> list[tuple[str, list[str], np.ndarray]]:
    """Planar parts whose depth mirror is a pose of the robot, seen nearly face-on.

    For each link: when its parent point and every tracked point beyond it lie in one plane, and that
    part mirrored in depth about the parent point is again a pose of the robot (reached by IK to a
    thousandth of the reach in nine frames of ten), the frames where the plane's normal is within
    ``max_angle`` (rad) of the camera's depth axis ``depth`` (F, 3). There the two branches meet and
    the tracks cannot tell which one the motion continues on. Returns (parent point, the joints the
    mirror turns, frame indices) per such part."""
    F = len(q)
    pos = robot.positions(q)
    index = {name: i for i, name in enumerate(robot.chain.joints)}
    reach = robot.reach()
    eye = _View.identity(F)
    found = []
    for b, (parent, _) in enumerate(robot.chain.bones):
        beyond = robot.chain.D[b] != 0
        rel = pos[:, beyond] - pos[:, index[parent], None]  # (F, n, 3)
        if rel.shape[1] < 2:
            continue
        _, sv, vt = np.linalg.svd(rel)
        if sv[:, -1].max() > 1e-6 * reach or (sv[:, 1] < 0.05 * sv[:, 0]).any():
            continue  # not a plane, or a line (a line's mirror is the axis's business)
        mirrored = _mirrored_beyond(pos, beyond, index[parent], depth)[0]
        q_m = _sequence_lm(robot, q, mirrored, np.ones(pos.shape[:2]), eye, np.ones((F, robot.nv), bool),
                           np.zeros(7, bool), 30, 1e-10, None)[0]
        reached = np.linalg.norm(robot.positions(q_m) - mirrored, axis=-1).max(1) < 1e-3 * reach
        frames = np.flatnonzero(np.abs(np.einsum("fd,fd->f", vt[:, -1], depth)) > np.cos(max_angle))
        if reached.mean() >= 0.9 and frames.size:
            turned = robot.v_mask(np.abs(_wrapped(robot, q_m - q))[reached].max(0) > 1e-3)
            found.append((parent, [robot.joint_names[k] for k in np.flatnonzero(turned)], frames))
    return found


def _frame_ranges(frames: np.ndarray) -> str:
    """'3-7, 12' for frames [3, 4, 5, 6, 7, 12]."""
    breaks = np.flatnonzero(np.diff(frames) > 1)
    starts, ends = np.r_[frames[0], frames[breaks + 1]], np.r_[frames[breaks], frames[-1]]
    return ", ".join(f"{a}" if a == e else f"{a}-{e}" for a, e in zip(starts, ends))


def _nearest_rest_branch(robot: RobotKinematics, q: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The path that puts every point where q (F, nq) puts it, on the branch nearest the rest pose.

    Tracked points on joint axes leave configurations that put every point in the same place (a wrist
    turned half a turn with the next joint mirrored). No image can choose among them; this picks, by
    the same dynamic programming as :func:`_viterbi_branches` on the 3D points (a continuous path,
    then nearness to the rest pose), and changes no point by more than a thousandth of the reach.
    Returns q itself when nothing changes."""
    pos = robot.positions(q)
    eye = _View.identity(len(q))
    tol = 1e-3 * robot.reach()
    alt = _viterbi_branches(robot, q, pos, np.ones(pos.shape[:2]), eye, free, 0.1 * tol, n_random=4)
    moved = np.linalg.norm(robot.positions(alt) - pos, axis=-1).max()
    if moved > tol or np.abs(_wrapped(robot, alt - q)).max() < 1e-3:
        return q
    return alt


def _turned_views(robot: RobotKinematics, q: np.ndarray, view: _View, gauge: np.ndarray,
                  turns: tuple[float, ...] = (0.5 * np.pi, np.pi, -0.5 * np.pi)) -> list[_View]:
    """Views that show the motion q (F, nq) as ``view`` shows it turned by ``turns`` (radians) about
    the axis of each joint in ``gauge`` (nv,): the gauge directions (for an arm on a floor, its first
    joint, whose turn the camera's azimuth imitates) and any other joint whose turn the camera's nearly
    imitates: starts for the smoothed search with q itself, and the gauge held in frame 0, as they are.
    Each view is fitted to the image of the turned robot.

    Why: how far round its base the camera stands is a guess of the start, and the smoothed search
    stays near the side it starts from; at 53 % hidden limbs a motion seen from below, with its first
    joint wandering 60 degrees, beat every start seen from above, though a motion 13 mm from the truth,
    found from a quarter turn, scores as well."""
    pos = robot.positions(q)
    views = []
    for v in np.flatnonzero(gauge):
        for turn in turns:
            dv = np.zeros((len(q), robot.nv))
            dv[:, v] = turn
            image = view.apply(robot.positions(robot.integrate(q, dv, clip=False)))[0]  # a turn, not a pose
            views.append(_camera_view(pos, image, np.ones(pos.shape[:2]), False))
    return views


# the reflection a mirror-symmetric robot's poses map onto one another by: the plane y = 0 of its base
# frame, in which such a robot's tracked points lie at rest (most arms; a pendulum), as for the weak
# fit's reflected candidate (chainspace.robot.fit)
SYMMETRY_MIRROR = np.diag([1.0, -1.0, 1.0])


def _base_keeping_mirror(robot: RobotKinematics, tracked: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
    """A reflection of base-frame points (F, J, 3) that leaves the ``tracked`` (J,) points no joint moves
    where they are: :data:`SYMMETRY_MIRROR` where they lie in its plane (an arm's base on its vertical
    axis), else the reflection through their own plane (a quadruped's trunk: base and hips). None where
    they span space. Every reflection of the tracked points is this one turned (a reflection times a
    reflection is a turn), so the mirror image of a motion is a pose of the robot, base held, when the
    reflected points are: a target for :func:`_far_poses` with the base where the robot has it."""
    static = tracked & ~_moves(robot).any(1)
    sp = robot.positions(robot.q_rest)[0, static]
    tol = 1e-6 * robot.reach()
    if len(sp) == 0 or np.abs(sp[:, 1]).max() <= tol:
        return lambda X: X @ SYMMETRY_MIRROR
    c0 = sp.mean(0)
    _, sv, vt = np.linalg.svd(sp - c0)
    if len(sv) == 3 and sv[2] > tol:
        return None
    n = vt[-1] if len(sv) > 1 else np.eye(3)[1]  # the plane's normal, or one across the line (or point)
    G = np.eye(3) - 2.0 * np.outer(n, n)
    return lambda X: (X - c0) @ G + c0


def _mirror_signs(robot: RobotKinematics, mirror: Callable[[np.ndarray], np.ndarray]) -> np.ndarray | None:
    """Signs s (nv,) such that the angles s * a pose the robot where ``mirror`` (a reflection of base-frame
    points (..., J, 3), as :func:`_base_keeping_mirror` returns) puts the points of a, for every a: -1
    for a joint whose axis lies in the mirror's plane, +1 for one across it (a mirror-symmetric arm). None
    where no such signs exist (a quadruped's legs mirror onto each other). Read joint by joint from the
    zero pose, checked on random poses."""
    nv = robot.nv
    turned = np.vstack([0.7 * np.eye(nv), -0.7 * np.eye(nv)])  # each joint alone, either way
    pos = robot.positions(robot.from_angles(turned)).reshape(2, nv, -1, 3)
    target = mirror(pos[0])
    s = np.where(np.abs(pos[1] - target).max((1, 2)) < np.abs(pos[0] - target).max((1, 2)), -1.0, 1.0)
    a = robot.angles(_random_q(robot, np.random.default_rng(0), 4))
    miss = np.abs(robot.positions(robot.from_angles(s * a)) - mirror(robot.positions(robot.from_angles(a)))).max()
    return s if miss < 1e-6 * robot.reach() else None


def _mirrored_motion(robot: RobotKinematics, q: np.ndarray, mirror: Callable[[np.ndarray], np.ndarray]
                     ) -> np.ndarray | None:
    """The motion (F, nq) whose points are q's (F, nq) reflected by ``mirror``, exactly, in every frame
    (:func:`_mirror_signs`: each joint's angle kept or negated; within the limits), or None where the
    robot has no such mirror."""
    s = _mirror_signs(robot, mirror)
    return None if s is None else robot.continuous(robot.clip(robot.from_angles(s * robot.angles(q))))


def _mirror_pose(robot: RobotKinematics, q: np.ndarray, free: np.ndarray, within: float = 1e-3) -> np.ndarray | None:
    """The motion (F, nq) that puts every tracked point where q (F, nq) puts it mirrored by
    :data:`SYMMETRY_MIRROR`, or None when the robot cannot take that pose (within ``within`` of its
    reach) in every frame: IK from q and from q's angles negated (the mirror of a symmetric arm)."""
    pos = robot.positions(q)
    target = pos @ SYMMETRY_MIRROR
    F = len(q)
    starts = [q, robot.from_angles(np.where(robot.turns_v, -robot.angles(q), robot.angles(q)))]
    qs = _sequence_lm(robot, np.concatenate(starts), np.concatenate([target] * 2), np.ones((2 * F, pos.shape[1])),
                      _View.identity(2 * F), np.tile(free, (2, 1)), np.zeros(7, bool), 30, 1e-10, None)[0]
    qs = qs.reshape(2, F, -1)
    miss = np.linalg.norm(robot.positions(qs.reshape(2 * F, -1)).reshape(2, F, -1, 3) - target, axis=-1).max((1, 2))
    k = int(np.argmin(miss))
    return robot.continuous(qs[k]) if miss[k] < within * robot.reach() else None


def _pinhole_twin(robot: RobotKinematics, q: np.ndarray, view, free: np.ndarray, within: float = 1e-3):
    """The motion and static pinhole camera (q (F, nq), view) that see the mirror image of the fit
    (q, ``view``) as that fit is seen, for a mirror-symmetric robot (:func:`_mirror_pose`, its points
    within ``within`` of the reach of the mirror image's); None for another robot.

    A fit in front of its camera: the mirror image turned to face the camera as the fit does (its depth
    mirrored about the robot's mean depth), which projects as the fit does up to perspective's share:
    under weak perspective exactly, the two sides of the mirror ambiguity. A start: refit it. A fit
    behind its camera (which a pinhole projects as it projects the points' reflection through the
    camera centre): the mirror image in front, an exact twin, camera ``-R S``, ``-t``.

    Why: each weak start is fitted under a camera of its own, and a fit's perspective twin need not be
    among them. The double pendulum through a pinhole (seed 0): objectives (robust squared residuals
    plus the motion prior, px^2; noise variance about 1.1) 169.0 for the true motion and 169.5 for its
    mirror image, a tie; from the turned starts alone the fit reached only the mirror's basin, 26
    degrees off, and reported it as settled."""
    qm = _mirror_pose(robot, q, free, within)
    if qm is None:
        return None
    R, t = view.R[0], view.t[0]
    depth = view.apply(robot.positions(q))[1][..., 2]
    if np.median(depth) < 0:
        R2, t2 = -R @ SYMMETRY_MIRROR, -t
    else:
        flip = np.diag([1.0, 1.0, -1.0])
        R2, t2 = flip @ R @ SYMMETRY_MIRROR, flip @ t + [0.0, 0.0, 2 * float(np.median(depth))]
    return qm, replace(view, R=R2[None], t=t2[None])


def _turned_twins(robot: RobotKinematics, q: np.ndarray, view) -> list:
    """The fit (q (F, nq), static pinhole ``view``) with its motion turned a quarter, a half and three
    quarters about the first joint's axis (:func:`chainspace.robot.starts._base_turns`) and the camera
    turned to match, so that every point the turn moves projects where it did: only the tracked points
    of the base off that axis tell them apart. [(q, view)]; none where the turn moves no tracked point
    the camera's turn does not imitate (the base's points on the axis: the joint is seen relative to
    frame 0, and the turn is the same motion).

    Why: joint1's offset against the camera's turn about its axis is seen through the base alone. The
    double pendulum through a pinhole (seed 13, its base point 0.035 m off the axis): the fit half a
    turn off on joint1 at objective 142.8, the true motion's mirror image 150.1 (noise variance about
    1.1), a tie no start reached, reported as settled."""
    from .starts import _base_turns

    pos = robot.positions(q)
    out = []
    for qt in _base_turns(robot, q):
        pt = robot.positions(qt)
        moved = np.linalg.norm(pt - pos, axis=-1) > 1e-9 * robot.reach()  # (F, J)
        if not moved.any():
            continue
        _, A, b = similarity_align(np.where(moved[..., None], pos, np.nan), np.where(moved[..., None], pt, np.nan),
                                   scale=False)  # the turn, x_t = A x + b
        v = _view_moved_with(view, A, b)
        if np.abs(v.apply(pt)[0] - view.apply(pos)[0]).max() < 1e-6 * max(view.f, 1.0):
            continue  # every tracked point where it was: the same motion up to the gauge
        out.append((qt, v))
    return out


# the turns about the base's line tried: of the motion as it is (the half turn, a twin of the whole arm
# about the line, and the quarter turns either way as further starts), and of its depth mirror turned
# back onto the base points (either of the two turns that do it: the half turn about the bisector of
# the line and its mirror image, or that and a half turn about the line)
STATIC_TURNS_DEG = (90.0, 180.0, 270.0)
STATIC_MIRROR_TURNS_DEG = (0.0, 180.0)


def _static_line_targets(robot, pos: np.ndarray, R0: np.ndarray, static: np.ndarray,
                         mirrors: bool = True) -> list[np.ndarray]:
    """3D targets (F, J, 3), base frame, that a weak-perspective camera turned about the line of the
    ``static`` (J,) base points sees as it sees ``pos`` (F, J, 3) through rotation R0 (base to camera):
    (a) pos turned about that line (:data:`STATIC_TURNS_DEG`); (b) pos mirrored in depth
    (the camera's third axis, about the base points' centre), as is or with the part beyond one link
    mirrored back (a depth flip of the mirrored motion: the base side mirrored, the far side carried
    along), then turned so that the base points are where they are (a half turn about the bisector of
    their line and its mirror image) and about their line (:data:`STATIC_MIRROR_TURNS_DEG`). Every tracked
    point projects where it did; only the base points are where the robot has them, the rest is a start
    for IK. Only (a) without ``mirrors`` (a pinhole camera: no depth mirror). [] when the base points do not
    lie on one line."""
    from scipy.spatial.transform import Rotation

    sp = pos[0, static]
    size = max(float(np.ptp(pos.reshape(-1, 3), axis=0).max()), 1e-9)
    if len(sp) < 2:
        return []
    c0 = sp.mean(0)
    _, sv, vt = np.linalg.svd(sp - c0)
    if sv[0] < 1e-3 * size or (len(sv) > 1 and sv[1] > 1e-6 * size):
        return []  # one point, or points that span a plane: no single line
    axis = vt[0]

    def turns(degrees):
        return [Rotation.from_rotvec(np.radians(t) * axis).as_matrix() for t in degrees]

    out = [(pos - c0) @ T.T + c0 for T in turns(STATIC_TURNS_DEG)]
    if not mirrors:
        return out
    M = R0.T @ np.diag([1.0, 1.0, -1.0]) @ R0  # the depth mirror, base frame
    b = axis + M @ axis
    if np.linalg.norm(b) < 1e-9:  # the line along the depth axis: its mirror image is itself, reversed
        b = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    G0 = Rotation.from_rotvec(np.pi * b / np.linalg.norm(b)).as_matrix()  # takes the mirrored line onto the line
    F = len(pos)
    n = np.broadcast_to(R0[2], (F, 3))
    index = {name: i for i, name in enumerate(robot.chain.joints)}
    Pm = (pos - c0) @ M.T + c0
    mirrored, seen_sets = [Pm], []
    for k, (parent, _) in enumerate(robot.chain.bones):
        beyond = robot.chain.D[k] != 0
        if beyond.sum() < 2 or static[beyond].any() or any((beyond == s).all() for s in seen_sets):
            continue  # a leaf (its own depth flip is the fit's), or a part already tried
        seen_sets.append(beyond)
        mirrored.append(_mirrored_beyond(Pm, beyond, index[parent], n)[0])
    out += [(P - c0) @ (T @ G0).T + c0 for P in mirrored for T in turns(STATIC_MIRROR_TURNS_DEG)]
    return out


def _static_line_starts(robot, lead: dict, tracks: np.ndarray, w: np.ndarray, tie_variances: float,
                        keep: int = 2) -> list[tuple[np.ndarray, object]]:
    """Starts (q (F, nq), view) for other basins that the camera's freedom about the base's tracked
    points allows: where the tracked points no joint moves lie on one line (two base points, say) and no
    joint turns about it (no gauge direction), they fix the camera only up to a turn about that line, or
    (weak perspective) a turn that mirrors them in depth. Per target of :func:`_static_line_targets` (the
    fit ``lead``'s 3D motion turned about the line, or, for a weak-perspective view, mirrored in depth
    with the part beyond one link carried along and turned back onto the base points), the robot is
    fitted to it along the sequence (IK from the rest pose's side, warm-started), the camera to the
    result (weak: in closed form; pinhole: the lead's camera turned as the motion was, then fitted), then
    everything to the tracks (a few steps, no prior). Starts whose squared residuals are no more than
    ``tie_variances`` noise variances above the lead's (or below), and that are not its own motion, are
    returned, best first, at most ``keep``.

    lead: q (F, nq), view (a static :class:`_View` or :class:`_PinholeView`), pos (F, J, 3) base frame,
    free, gauge, delta (Huber), sse (its squared residuals, px^2) and var (its noise variance, px^2).

    Why: TALOS's left arm hangs from two tracked base points (arm_left_1_link, arm_left_2_link) whose
    line is no joint's axis. Weak camera, full ranges, 30 frames: seed 0 reported the whole arm turned
    174 degrees about that line (arm_left_2 38, arm_left_3 175 degrees off; every tracked point within
    2 mm of the truth's in the camera's frame), 30 noise variances above the true motion's basin; seed 2
    reported the base line and upper arm mirrored in depth with the forearm carried along (four joints
    2-40 degrees off, as well fitted as the truth). Neither the fit's mirrors and depth flips nor IK on
    its own 3D points reach those basins (their points lie 0.2-0.8 m from the truth's in the base
    frame: the camera differs). Through the same arm's pinhole camera with its intrinsics (seed 3 from
    above), the fit ended the whole arm turned about the line again (arm_left_2 42, arm_left_3 167
    degrees off), 94 noise variances above the true motion's basin, which none of its starts reached."""
    from .starts import _sequential_ik

    q, view, pos, gauge, free = (lead[k] for k in ("q", "view", "pos", "gauge", "free"))
    if np.asarray(gauge).any() or getattr(view, "per_frame", False):
        return []
    F = len(q)
    pinhole = isinstance(view, _PinholeView)
    static = (w > 0).any(0) & ~_moves(robot).any(1)  # tracked points that no joint moves
    targets = _static_line_targets(robot, pos, view.R[0], static, mirrors=not pinhole)
    if not targets:
        return []
    sse0, var = lead["sse"], lead["var"]
    ones3, ident = np.ones(pos.shape[:2]), _View.identity(F)
    turn = np.array([True, True, True, False, True, True, True])  # rotation, (not scale), translation
    found: list[tuple[float, np.ndarray, object]] = []
    for X in targets:
        qa = _sequential_ik(robot, X, ones3, ident, free, robot.q_seed, gauge)
        # the turn is only a start: the robot fitted to the target turned as a whole (one turn and shift for
        # the sequence, the base points holding it to the turn about their line)
        qa = _sequence_lm(robot, qa, X, ones3, ident, free, turn, 30, 1e-8, None)[0]
        pa = robot.positions(qa)
        va = _turned_camera(view, pos, pa, tracks, w, robot, qa, free, lead["delta"]) if pinhole else \
            _camera_view(pa, tracks, w, False)
        qa, va, rna, _, _, _ = _sequence_lm(robot, qa, tracks, w, va, free, np.ones(va.n_params, bool), 30, 1e-8,
                                            lead["delta"])
        s = float((w * rna ** 2).sum())
        if s - sse0 > tie_variances * var or _same_motion(robot, qa, q) or \
                any(_same_motion(robot, qa, o) for _, o, _ in found):
            continue
        found.append((s, qa, va))
    found.sort(key=lambda x: x[0])
    return [(qa, va) for _, qa, va in found[:keep]]


def _turned_camera(view, pos: np.ndarray, pa: np.ndarray, tracks: np.ndarray, w: np.ndarray, robot, qa: np.ndarray,
                   free: np.ndarray, delta: float | None):
    """The static pinhole ``view`` of motion ``pos`` (F, J, 3) turned and shifted as the motion was to
    ``pa`` (the rigid motion that fits best), so that ``pa`` projects where ``pos`` did, then fitted alone
    to the tracks with the robot held at ``qa``."""
    _, A, b = similarity_align(pos, pa, scale=False)  # pa ~ A pos + b
    v = _view_moved_with(view, A, b)
    return _sequence_lm(robot, qa, tracks, w, v, np.zeros_like(free), np.ones(v.n_params, bool), 30, 1e-10, delta)[1]


def _view_moved_with(view, A: np.ndarray, b: np.ndarray):
    """The static pinhole ``view`` turned and shifted with the scene: where the base-frame points move
    rigidly, x -> A x + b, the returned view sees each moved point where ``view`` saw it."""
    R = view.R[0] @ A.T
    return replace(view, R=R[None], t=(view.t[0] - R @ b)[None])
