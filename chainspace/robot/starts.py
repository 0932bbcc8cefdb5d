"""Where the fit starts: rotations spread over SO(3), a camera from the first frames, IK along the
sequence warm-started from the previous frames, and the 3D fit to a reconstruction.
"""

from __future__ import annotations

import numpy as np

from .kinematics import RobotKinematics, _held_q, _random_q, _rest_distance, _seeded, _wrapped
from .views import _View, _align, _camera_view
from .solver import _sequence_lm
from .observability import _point_movers


def _rotation_candidates(n_directions: int, n_azimuths: int) -> np.ndarray:
    """Rotations spread over SO(3): the base's z axis sent to Fibonacci-sphere directions, each with
    a few turns about it. (n, 3, 3)."""
    from scipy.spatial.transform import Rotation

    k = np.arange(n_directions) + 0.5
    z = 1 - 2 * k / n_directions
    phi = np.pi * (1 + 5 ** 0.5) * k
    dirs = np.stack([np.sqrt(1 - z ** 2) * np.cos(phi), np.sqrt(1 - z ** 2) * np.sin(phi), z], -1)
    out = []
    for d in dirs:
        tilt = Rotation.align_vectors([d], [[0, 0, 1]])[0]
        for a in np.arange(n_azimuths) * 2 * np.pi / n_azimuths:
            out.append((tilt * Rotation.from_rotvec([0, 0, a])).as_matrix())
    return np.array(out)


def _initial_view(robot: RobotKinematics, X: np.ndarray, w: np.ndarray, free: np.ndarray, transform: str,
                  n_frames: int = 4, rounds: int = 3) -> _View:
    """A first view of the base frame onto X (F, J, 3), found by trying rotations.

    Scale from the bone lengths (constant for links joined by revolute joints), translation from the
    root (fixed to the base). Candidates: the rest pose's closed-form alignment and rotations spread
    over SO(3). For each, on ``n_frames`` frames spread over the sequence (all candidates in one
    batched solve), a few rounds of IK from the rest pose and closed-form re-alignment; the candidate
    with the lowest residual wins. A local method started from the rest pose's alignment alone lands in
    a wrong pose when the robot works far from its rest pose.
    """
    x_rest = robot.positions(robot.q_rest)[0]
    aligned = _align(x_rest, X, w, transform)
    if transform == "none":
        return aligned
    F = len(X)
    seen = w > 0
    links = [(robot.chain.joint_index(a), robot.chain.joint_index(b)) for a, b in robot.chain.links]
    L_rec = np.array([np.median(np.linalg.norm(X[:, b] - X[:, a], axis=-1)[seen[:, a] & seen[:, b]])
                      if (seen[:, a] & seen[:, b]).any() else np.nan for a, b in links])
    L_mod = np.array([np.linalg.norm(x_rest[b] - x_rest[a]) for a, b in links])
    ok = np.isfinite(L_rec) & (L_mod > 1e-3 * L_mod.max())
    s = float(np.median(L_rec[ok] / L_mod[ok])) if ok.any() and transform == "similarity" else aligned.S[0]
    r = robot.chain.joint_index(robot.chain.root)
    good = np.flatnonzero(seen.sum(1) >= 3)
    frames = (good if len(good) else np.arange(F))[np.unique(np.linspace(0, max(len(good), 1) - 1,
                                                                          n_frames).round().astype(int))]
    Rs = np.concatenate([aligned.R, _rotation_candidates(16, 3)])
    root_X = np.median(X[seen[:, r], r], axis=0) if seen[:, r].any() else aligned.T[0]
    n_c, n_f = len(Rs), len(frames)
    S, T = np.full(n_c, s), root_X - s * Rs @ x_rest[r]
    q = np.array(np.broadcast_to(robot.q_seed, (n_c * n_f, robot.nq)))
    best, _ = _best_candidate_view(robot, q, X, w, free, frames, S, Rs, T, 7, rounds,
                                   lambda pos: _align(pos, X[frames], w[frames], transform))
    return _View(S[best:best + 1], Rs[best][None], T[best][None], np.zeros(F, int))


def _best_candidate_view(robot: RobotKinematics, q: np.ndarray, target: np.ndarray, w: np.ndarray,
                         free: np.ndarray, frames: np.ndarray, S: np.ndarray, Rs: np.ndarray, T: np.ndarray,
                         n_view: int, rounds: int, realign) -> tuple[int, np.ndarray]:
    """Index of the candidate view (S, Rs, T, updated in place) whose IK on ``frames`` fits best.

    Every candidate's IK runs in one batched solve from ``q`` ((candidates x frames, nq)); between
    rounds each candidate's view is re-fitted by ``realign(positions (frames, J, 3))`` to its own IK
    solutions. ``n_view`` is the number of view parameters (7 for a 3D similarity, 6 for a camera),
    held fixed here. Returns (best index, q of every candidate and frame).
    """
    n_c, n_f = len(Rs), len(frames)
    idx = np.tile(frames, n_c)
    for k in range(rounds):
        cand = _View(np.repeat(S, n_f), np.repeat(Rs, n_f, 0), np.repeat(T, n_f, 0), np.arange(n_c * n_f))
        q, _, rn, pos, _, _ = _sequence_lm(robot, q, target[idx], w[idx], cand, free[idx], np.zeros(n_view, bool),
                                           15, 1e-6, None)
        if k + 1 < rounds:
            pos = pos.reshape(n_c, n_f, -1, 3)
            for c in range(n_c):
                v = realign(pos[c])
                S[c], Rs[c], T[c] = v.S[0], v.R[0], v.T[0]
    err = np.sqrt((w[idx] * rn ** 2).sum(1) / np.maximum(w[idx].sum(1), 1e-300)).reshape(n_c, n_f)
    return int(np.argmin(np.median(err, axis=1))), q


def _initial_camera(robot: RobotKinematics, u: np.ndarray, w: np.ndarray, free: np.ndarray,
                    n_frames: int = 6, rounds: int = 3) -> tuple[_View, np.ndarray]:
    """A static weak-perspective camera found from the 2D tracks u (F, J, 2) alone, by trying rotations.

    The same search as :func:`_initial_view`, in the image: scale from the links' longest projections
    (a link is never seen longer than it is), translation from the root, rotations over SO(3); a few
    rounds of per-frame IK and closed-form camera refits on ``n_frames`` frames; the candidate with
    the lowest reprojection error wins. A poor monocular reconstruction (robots near singular poses)
    no longer decides the camera. Returns (view for all F frames, q (F, nq) from the best candidate's
    first frame).
    """
    F = len(u)
    x_rest = robot.positions(robot.q_rest)[0]
    seen = w > 0
    links = [(robot.chain.joint_index(a), robot.chain.joint_index(b)) for a, b in robot.chain.links]
    L_mod = np.array([np.linalg.norm(x_rest[b] - x_rest[a]) for a, b in links])
    ratio = [np.percentile(np.linalg.norm(u[:, b] - u[:, a], axis=-1)[seen[:, a] & seen[:, b]], 95) / L
             for (a, b), L in zip(links, L_mod) if L > 1e-2 * L_mod.max() and (seen[:, a] & seen[:, b]).sum() > 3]
    s = float(np.median(ratio)) if ratio else 1.0
    r = robot.chain.joint_index(robot.chain.root)
    good = np.flatnonzero(seen.sum(1) >= 3)
    frames = (good if len(good) else np.arange(F))[np.unique(np.linspace(0, max(len(good), 1) - 1,
                                                                          n_frames).round().astype(int))]
    Rs = _rotation_candidates(24, 4)
    root_u = np.median(u[seen[:, r], r], axis=0) if seen[:, r].any() else np.nanmedian(u.reshape(-1, 2), 0)
    n_c, n_f = len(Rs), len(frames)
    S, T = np.full(n_c, s), root_u - s * (Rs @ x_rest[r])[:, :2]
    idx = np.tile(frames, n_c)
    uz = np.nan_to_num(u)
    q = _seeded(robot, np.broadcast_to(robot.q_rest, (len(idx), robot.nq)), free[idx])
    best, q = _best_candidate_view(robot, q, uz, w, free, frames, S, Rs, T, 6, rounds,
                                   lambda pos: _camera_view(pos, uz[frames], w[frames], False))
    q0 = q.reshape(n_c, n_f, -1)[best, 0]
    return _View(S[best:best + 1], Rs[best][None], T[best][None], np.zeros(F, int)), \
        np.array(np.broadcast_to(q0, (F, robot.nq)))


def _sequential_ik(robot: RobotKinematics, X: np.ndarray, w: np.ndarray, view: _View, free: np.ndarray,
                   q_first: np.ndarray, gauge: np.ndarray, q_alt: np.ndarray | None = None,
                   block: int = 6) -> np.ndarray:
    """IK along the sequence, warm-started from the previous frames: a continuous path.

    Frames go in blocks of ``block`` (solved together, each block started from the last solution of
    the one before), which keeps the warm start a fraction of a second of motion away and the solves
    batched. Every frame is also solved from q_alt (default the rest pose); where both fit alike
    (within 1.5 times), the solution nearer q_alt (default: nearer the rest pose) is kept. This keeps
    the path on the rest pose's branch where it
    passes a singularity (a wrist stretched straight), after which warm starts alone may continue on
    a flipped branch that fits the points just as well.
    """
    F = len(X)
    q = np.empty((F, robot.nq))
    prev = q_first
    fixed_view = np.zeros(view.n_params, bool)
    if q_alt is None and (free[1:] == free[1:2]).all() and (free[0] <= free[-1]).all():
        # the directions held after frame 0 are held in every frame (frame 0 may hold more: a static
        # camera's gauge joint), so they keep q_first's values all along and the starts from the rest
        # pose's side do not depend on the path: they are solved for all frames at once, and the
        # blocks wait only for the warm-started solves, which converge in a few steps
        q_alt_fixed = _seeded(robot, np.broadcast_to(q_first, (F, robot.nq)), free)
        alt_all = _sequence_lm(robot, q_alt_fixed, X, w, view, free, fixed_view, 30, 1e-8, None)
    elif q_alt is not None:
        alt_all = _sequence_lm(robot, q_alt, X, w, view, free, fixed_view, 30, 1e-8, None)
    else:
        alt_all = None
    for a in range(0, F, block):
        idx = np.arange(a, min(a + block, F))
        n = len(idx)
        both = np.concatenate([idx, idx])
        if alt_all is None:
            alt = _seeded(robot, np.broadcast_to(prev, (n, robot.nq)), free[idx])
            q0 = np.concatenate([np.broadcast_to(prev, (n, robot.nq)), alt])
            qs, _, rn, _, _, _ = _sequence_lm(robot, q0, X[both], w[both], view.take(both), free[both],
                                              fixed_view, 30, 1e-8, None)
        else:
            alt = q_alt_fixed[idx] if q_alt is None else q_alt[idx]
            qs, _, rn, _, _, _ = _sequence_lm(robot, np.array(np.broadcast_to(prev, (n, robot.nq))), X[idx], w[idx],
                                              view.take(idx), free[idx], fixed_view, 30, 1e-8, None)
            qs, rn = np.concatenate([qs, alt_all[0][idx]]), np.concatenate([rn, alt_all[2][idx]])
        err = np.sqrt((w[both] * rn ** 2).sum(1)).reshape(2, n)
        if q_alt is None:
            d = _rest_distance(robot, qs, prev, gauge).reshape(2, n)
        else:  # prefer the solution nearer q_alt (the 3D fit: it knows which way each link leans in depth)
            d = np.abs(_wrapped(robot, qs - np.concatenate([alt, alt]))).sum(-1).reshape(2, n)
        tied = err.max(0) <= 1.5 * err.min(0) + 1e-9 * view.S[0]
        pick = np.where(tied, np.argmin(d, 0), np.argmin(err, 0))
        q[idx] = qs.reshape(2, n, -1)[pick, np.arange(n)]
        prev = q[idx[-1]]
    return q


def _branch_near_rest(robot: RobotKinematics, Y: np.ndarray, w: np.ndarray, view: _View, free: np.ndarray,
                      q_now: np.ndarray, gauge: np.ndarray, n_seeds: int = 48, seed: int = 0) -> np.ndarray:
    """Of the joint angles that fit one frame's points Y (J, 3) equally well, the nearest the rest pose.

    Tracked points on joint axes leave discrete ambiguities (a wrist turned half a turn with the next
    joint mirrored puts every point in the same place); the data cannot choose, so the branch of the
    rest pose is taken, found by IK from many seeds.
    """
    rng = np.random.default_rng(seed)
    seeds = _random_q(robot, rng, n_seeds)
    seeds = np.concatenate([robot.q_rest[None], robot.q_seed[None], q_now[None], seeds])
    held = _held_q(robot, free)  # the q entries of the held directions (both of a continuous joint's)
    seeds[:, held] = q_now[held]
    n = len(seeds)
    v = _View(view.S, view.R, view.T, np.zeros(n, int))
    q, _, rn, _, _, _ = _sequence_lm(robot, seeds, np.broadcast_to(Y, (n,) + Y.shape),
                                     np.broadcast_to(w, (n,) + w.shape), v, np.broadcast_to(free, (n, robot.nv)),
                                     np.zeros(7, bool), 40, 1e-10, None)
    err = np.sqrt((w * rn ** 2).sum(1) / max(w.sum(), 1e-300))
    tied = err <= err.min() * 1.5 + 1e-9 * max(view.S[0], 1e-300)
    d = _rest_distance(robot, q, robot.q_rest, gauge)
    k = np.flatnonzero(tied)[np.argmin(d[tied])]
    return robot.wrap_near(q[k:k + 1], robot.q_rest)[0]


def _fit_3d(robot: RobotKinematics, X: np.ndarray, w: np.ndarray, free: np.ndarray, transform: str,
            max_iter: int, tol: float, gauge: np.ndarray, rounds: int = 5) -> tuple[np.ndarray, _View, int]:
    """Joint angles and one view onto the 3D points X (F, J, 3).

    Start: a view found by trying rotations (:func:`_initial_view`), then IK frame by frame from the
    rest pose's branch, each frame warm-started from the previous one. Then alternate the closed-form
    alignment with per-frame IK (each frame with its own damping: robust far from the solution); the
    coupled Levenberg-Marquardt of joint angles and view together polishes afterwards.
    """
    fixed_view = np.zeros(7, bool)
    view = _initial_view(robot, X, w, free, transform)
    n_iter = 0
    for attempt in range(2):
        q_first = _branch_near_rest(robot, X[0], w[0], view.take(np.array([0])), free[0],
                                    robot.q_rest if attempt == 0 else q[0], gauge)
        if attempt == 1 and np.abs(_wrapped(robot, q_first - q[0])).max() < 1e-3:
            break  # the branch did not change
        q = _sequential_ik(robot, X, w, view, free, q_first, gauge)
        prev_rms = np.inf
        for _ in range(rounds if transform != "none" else 1):
            view = _align(robot.positions(q), X, w, transform)
            q, view, rn, _, _, it = _sequence_lm(robot, q, X, w, view, free, fixed_view, 10, 1e-8, None)
            n_iter += it
            rms = float(np.sqrt((w * rn ** 2).sum() / w.sum()))
            if rms > (1 - 1e-2) * prev_rms:
                break
            prev_rms = rms
    return q, view, n_iter


def _whole_turn_joint(robot: RobotKinematics, q: np.ndarray) -> int | None:
    """The first revolute joint (its index among the degrees of freedom) that turns every tracked point
    any joint moves, in the first frame of q (F, nq): an arm's first joint; None for a tree of legs."""
    moves = _point_movers(robot, q[:1])  # (J, nv)
    moved = moves.any(1)
    whole = np.flatnonzero(robot.turns_v & (moves | ~moved[:, None]).all(0) & moves.any(0))
    return int(whole[0]) if whole.size else None


def _base_turns(robot: RobotKinematics, q: np.ndarray,
                turns: tuple[float, ...] = (0.5 * np.pi, np.pi, -0.5 * np.pi)) -> list[np.ndarray]:
    """The motion q (F, nq) turned by ``turns`` (radians) about the axis of the first joint that turns
    every tracked point any joint moves (an arm's first joint; none for a tree of legs): starts for a
    static camera, which sees such a turn as a turn of itself, except through the tracked points of the
    base off that axis. [] when no joint qualifies.

    Why: the weak fit's camera is a guess of how far round that axis it stands, and from a wrong
    guess the perspective fit stays in a wrong basin. The double pendulum through a pinhole (seed 7,
    0.3 m away): every weak start tens of degrees off on joint1 (one nearly half a turn), the fit 91
    degrees off, 5.6 px RMS on 1 px tracks; the true motion's basin, its objective 17 times lower, was
    reached from a quarter turn of one of them."""
    k = _whole_turn_joint(robot, q)
    if k is None:
        return []
    out = []
    for turn in turns:
        dv = np.zeros((len(q), robot.nv))
        dv[:, k] = turn
        out.append(robot.integrate(q, dv, clip=False))  # a turn, not a pose: the limits are the fit's to keep
    return out
