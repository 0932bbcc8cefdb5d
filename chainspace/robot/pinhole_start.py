"""A start for the perspective fit that owes nothing to weak perspective: the static pinhole camera
searched on a few frames, then every frame's joints by IK under it (:func:`pinhole_start`).

Why: the perspective fit (:mod:`chainspace.robot.perspective`) starts from the weak-perspective fit's
motions, and a robot close to a wide lens is far from weak perspective. The milling arm with its
nearest point 0.3 m from a 90-degree lens (300 frames, 1 px noise, seed 0): the weak starts are 9-130
degrees off per joint, and the perspective fit from them leaves squared residuals about 8 times what
the noise allows, where a fit started from the true motion ends at the noise (joints 0.04-0.33
degrees off). The camera is static and the URDF fixes the robot's scale, so one camera pose serves
every frame: it is searched as :func:`chainspace.robot.starts._initial_camera` searches the weak one
(rotations spread over SO(3), IK on a few frames under each), in full perspective, and the best
candidates are fitted with their frames' joints (camera free, robust loss). On that film the search
finds the camera (its frames at 2.3 px^2 per point, the noise's level) in 1.4 s of CPU. The camera is
then fitted with the joints by Levenberg-Marquardt rather than by OpenCV's PnP on IK points: that
alternation, started from the true camera, stalled 1.4 degrees off at 300 times the noise's cost.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .compiled import map_tasks
from .kinematics import RobotKinematics, _held_q, _random_q, _seeded
from .solver import _sequence_lm
from .starts import _rotation_candidates, _sequential_ik
from .uncertainty import track_jitter
from .views import _PinholeView, _pinhole_pixels, _pinhole_pixels_by_point, turn_between_deg

# the search's frames (spread over the sequence); depths of the robot's root tried per rotation, as
# multiples of the depth its image size suggests (f / px per metre, which a robot reaching towards the
# lens makes too small)
SEARCH_FRAMES = 6
DEPTH_FACTORS = (1.0, 2.0, 4.0)
# candidate cameras of the search fitted with the joints of its frames (camera free), the IK's random
# seeds per frame, and the Huber threshold of that fit as a fraction of the tracks' extent
N_REFINED = 8
N_RANDOM_SEEDS = 8
# refined candidates whose rotations lie closer than this are one camera (:func:`search_cameras`)
DISTINCT_CAMERA_DEG = 5.0
# a frame whose best squared residuals exceed this many times what the noise allows gets RETRY_SEEDS more
RETRY_ABOVE_NOISE = 5.0
RETRY_SEEDS = 96
# a searched camera under which every seed misses more than this share of the frames is no start where
# the caller's winner fits the tracks at the noise (pinhole_start's ``missed_max``): an arm's seeds under
# the robot's camera missed a minority (the milling arm at close range: 69 of 300 frames; the Panda,
# full ranges from below, 30 frames, seed 52: 5 of 30, its start the truth's basin); under a wrong one,
# every frame (the milling arm at 1.5-3 reaches, 300 frames: all 300 at 80 times the noise, and still
# after the retry's seeds; refined, it ended 130 times above the winner: 2.9 s of a 12 s fit on two
# threads; the Panda close to a 90-degree lens: 300 of 300 at 500 times, ended 575 times above). Not
# where the winner is poor: a quadruped's seeds miss 70-100 % of the frames under its camera (A1 and
# Solo12, full ranges, seeds 52-53), and its searched start then beat the poor winner
MOST_MISSED = 0.5
# a joint step between frames that costs as much as a noise variance of squared residuals in the
# choice of a continuous path (:func:`_smooth_path`): a wrist's twin (half a turn) costs about 4,000
PATH_STEP_RAD = 0.05
HUBER_EXTENT = 0.01


@dataclass
class _PinholeCandidates(_PinholeView):
    """Several pinhole cameras of one K held fixed for the solvers: frame f (a candidate's copy of a
    search frame) is seen by camera ``cam_of[f]`` (R (C, 3, 3), t (C, 3)). Only the point Jacobian is
    given: the solvers move the joints alone."""

    def apply(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y = np.einsum("fij,fkj->fki", self.R[self.cam_of], x) + self.t[self.cam_of][:, None]
        return _pinhole_pixels(self.f, self.c, y), y

    def derivatives(self, y: np.ndarray) -> tuple[np.ndarray, None]:
        return _pinhole_pixels_by_point(self.f, y) @ self.R[self.cam_of][:, None], None

    @property
    def S(self) -> np.ndarray:
        return np.ones(len(self.R))

    def take(self, idx: np.ndarray) -> _PinholeCandidates:
        return _PinholeCandidates(self.R, self.t, self.f, self.c, self.cam_of[idx])

    def put(self, idx, sub, accept) -> _PinholeCandidates:
        return self  # held: nothing of the cameras moves


def _cost(rn: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per candidate (rows of rn (C, n_f, J)) the median over its frames of the mean squared residual:
    a frame that IK left on a poor branch does not sink a right camera."""
    return np.median((w * rn ** 2).sum(-1) / np.maximum(w.sum(-1), 1e-300), axis=-1)


def _multi_seed_ik(robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, view: _PinholeView,
                   free: np.ndarray, n_random: int = N_RANDOM_SEEDS, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's joint angles under the held camera ``view`` from the rest pose, the solver's two
    seeds and ``n_random`` random poses (held directions at rest): (q (F, S, nq), squared residuals
    (F, S)) of every seed. One batched solve.

    Why many seeds: at close range one seed's IK stops in a wrong local minimum in many frames even
    under the true camera (the milling arm, 300 frames: 169 frames missed from the rest pose's side
    warm-started along the sequence, 37 with the best of 11 seeds)."""
    F = len(tracks)
    seeds = np.concatenate([robot.q_rest[None], robot.q_seed[None], robot.q_seed_other[None],
                            _random_q(robot, np.random.default_rng(seed), n_random)])
    S = len(seeds)
    idx = np.repeat(np.arange(F), S)
    q = np.where(_held_q(robot, free[idx]), robot.q_rest, np.tile(seeds, (F, 1)))
    many = _PinholeView(view.R, view.t, view.f, view.c, np.zeros(len(idx), int))
    q, _, rn, _, _, _ = _sequence_lm(robot, q, tracks[idx], w[idx], many, free[idx], np.zeros(6, bool), 30, 1e-6,
                                     None)
    return q.reshape(F, S, -1), (w[idx] * rn ** 2).sum(1).reshape(F, S)


def _best_of(q: np.ndarray, err: np.ndarray) -> np.ndarray:
    """Per frame the solution of lowest error: q (F, S, nq), err (F, S) -> (F, nq)."""
    return q[np.arange(len(q)), err.argmin(1)]


def _smooth_path(robot: RobotKinematics, q: np.ndarray, err: np.ndarray, sigma2: float) -> np.ndarray:
    """The path through each frame's IK solutions q (F, S, nq) (squared residuals err (F, S)) that
    minimises err / sigma2 plus (joint step / :data:`PATH_STEP_RAD`)^2 summed over the frames
    (dynamic programming): (F, nq).

    Why: seeds end on either of a wrist's exact twins (every tracked point in the same place) at
    random, and a path that jumps between them frame to frame is no start for the smoothed fit."""
    F, S, _ = q.shape
    a = robot.angles(q.reshape(F * S, -1)).reshape(F, S, -1)
    unary = err / max(sigma2, 1e-12)
    total, back = unary[0], np.zeros((F, S), int)
    for f in range(1, F):
        step = (robot.wrap_angles(a[f][None, :] - a[f - 1][:, None]) ** 2).sum(-1) / PATH_STEP_RAD ** 2
        cand = total[:, None] + step  # (previous, current)
        back[f] = cand.argmin(0)
        total = cand.min(0) + unary[f]
    pick = np.empty(F, int)
    pick[-1] = int(total.argmin())
    for f in range(F - 1, 0, -1):
        pick[f - 1] = back[f, pick[f]]
    return q[np.arange(F), pick]


def _bridged(robot: RobotKinematics, q: np.ndarray, tracks: np.ndarray, w: np.ndarray, view: _PinholeView,
             free: np.ndarray, poor: float) -> np.ndarray:
    """The path q (F, nq) with each run of poorly fitted frames (squared residuals above ``poor`` per
    seen point) refitted from the straight line (in joint angles) between the well fitted frames on
    either side, where that fits better.

    Why: the seeds that fit such frames can end on the other of a wrist's exact twins than the path
    around them, and the continuous path then keeps a poor fit there (the milling arm at close range:
    frames 164-177 at 100 times the noise, fitted by seeds on the other twin); from the line between
    its neighbours IK finds the fit on the path's own branch."""
    rn = np.linalg.norm(view.apply(robot.positions(q))[0] - tracks, axis=-1)
    bad = (w * rn ** 2).sum(1) > poor * np.maximum((w > 0).sum(1), 1)
    good = np.flatnonzero(~bad)
    if not bad.any() or not len(good):
        return q
    a = robot.angles(q)
    idx = np.flatnonzero(bad)
    before = good[np.clip(np.searchsorted(good, idx) - 1, 0, None)]
    after = good[np.clip(np.searchsorted(good, idx), None, len(good) - 1)]
    span = np.where(after > before, after - before, 1)
    frac = np.clip((idx - before) / span, 0, 1)[:, None]
    line = a[before] + frac * robot.wrap_angles(a[after] - a[before])
    q0 = np.where(_held_q(robot, free[idx]), q[idx], robot.from_angles(line))
    q1, _, rn1, _, _, _ = _sequence_lm(robot, q0, tracks[idx], w[idx], view.take(idx), free[idx], np.zeros(6, bool),
                                       30, 1e-6, None)
    better = (w[idx] * rn1 ** 2).sum(1) < (w[idx] * rn[idx] ** 2).sum(1)
    out = q.copy()
    out[idx[better]] = q1[better]
    return out


def search_camera(robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, free: np.ndarray,
                  K: np.ndarray, frames: np.ndarray) -> tuple[float, _PinholeView, np.ndarray] | None:
    """The static pinhole camera (known K (3, 3), square pixels) that best explains the tracks (F, J, 2)
    of ``frames``, with their joint angles: (median over the frames of the mean squared residual px^2,
    camera, q (len(frames), nq)); None when no candidate sees every point in front of it. The first of
    :func:`search_cameras`."""
    ranked = search_cameras(robot, tracks, w, free, K, frames)
    return ranked[0] if ranked else None


def search_cameras(robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, free: np.ndarray,
                   K: np.ndarray, frames: np.ndarray) -> list[tuple[float, _PinholeView, np.ndarray]]:
    """The candidates of :func:`search_camera`, each as (cost, camera, q), lowest cost first: those that
    see every point in front of them, and distinct (rotations more than :data:`DISTINCT_CAMERA_DEG` apart:
    refined candidates often meet).

    Rotations spread over SO(3) (:func:`chainspace.robot.starts._rotation_candidates`), each with the
    robot's root on its track at :data:`DEPTH_FACTORS` times the depth its image size suggests, ranked
    by IK on the frames from one seed (all candidates in one batched solve); the :data:`N_REFINED`
    best then get IK from many seeds (:func:`_multi_seed_ik`) and the camera is fitted with the joints
    (robust loss: a frame left on a wrong branch does not pull the camera off); of those, the lowest
    cost is kept. The grid's spacing (about 30 degrees) is within that fit's reach: the milling arm at
    close range, from the true camera turned 30 degrees about random axes, returned to it in 6 of 6
    trials."""
    f, c = float(K[0, 0]), K[:2, 2]
    x_rest = robot.positions(robot.q_rest)[0]
    seen = w > 0
    links = [(robot.chain.joint_index(a), robot.chain.joint_index(b)) for a, b in robot.chain.links]
    L = np.array([np.linalg.norm(x_rest[b] - x_rest[a]) for a, b in links])
    ratio = [np.median(np.linalg.norm(tracks[:, b] - tracks[:, a], axis=-1)[seen[:, a] & seen[:, b]]) / l
             for (a, b), l in zip(links, L) if l > 1e-2 * L.max() and (seen[:, a] & seen[:, b]).sum() > 3]
    s = float(np.median(ratio)) if ratio else f  # px per metre
    r = robot.chain.joint_index(robot.chain.root)
    root_u = np.median(tracks[seen[:, r], r], axis=0) if seen[:, r].any() else c
    ray = np.append((root_u - c) / f, 1.0)
    rots = _rotation_candidates(24, 4)
    Rs = np.concatenate([rots] * len(DEPTH_FACTORS))
    depth = np.repeat(np.array(DEPTH_FACTORS) * f / s, len(rots))
    ts = depth[:, None] * ray - Rs @ x_rest[r]
    n_c, n_f = len(Rs), len(frames)
    idx = np.tile(frames, n_c)
    uz = np.nan_to_num(tracks)
    q = _seeded(robot, np.broadcast_to(robot.q_rest, (len(idx), robot.nq)), free[idx])
    cams = _PinholeCandidates(Rs, ts, f, c, np.repeat(np.arange(n_c), n_f))
    rn = _sequence_lm(robot, q, uz[idx], w[idx], cams, free[idx], np.zeros(6, bool), 30, 1e-6, None)[2]
    cost = _cost(rn.reshape(n_c, n_f, -1), w[frames][None])
    extent = float(max(np.ptp(uz[..., 0][seen]), np.ptp(uz[..., 1][seen])))
    # every one of them refined, the best kept: where few tracked points move (the double pendulum: one),
    # a candidate can fit the search's few frames within the noise and still be another motion's camera,
    # so the first one within the noise ends nothing
    def refined(j):  # candidate j's camera fitted with its frames' joints, on a thread of its own
        view = _PinholeView(Rs[j][None].copy(), ts[j][None].copy(), f, c, np.zeros(n_f, int))
        qj = _best_of(*_multi_seed_ik(robot, uz[frames], w[frames], view, free[frames]))
        qj, view, rnj, _, _, _ = _sequence_lm(robot, qj, uz[frames], w[frames], view, free[frames], np.ones(6, bool),
                                              100, 1e-10, HUBER_EXTENT * extent)
        return float(_cost(rnj[None], w[frames][None])[0]), view, qj

    ranked: list[tuple[float, _PinholeView, np.ndarray]] = []
    for cj, view, qj in sorted(map_tasks(robot, refined, np.argsort(cost)[:N_REFINED]), key=lambda r: r[0]):
        if view.apply(robot.positions(qj))[1][..., 2].min() > 0 and not any(
                turn_between_deg(view.R[0], o[1].R[0]) <= DISTINCT_CAMERA_DEG for o in ranked):
            ranked.append((cj, view, qj))
    return ranked


def pinhole_start(robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, free: np.ndarray,
                  gauge: np.ndarray, K: np.ndarray,
                  skip: Callable[[_PinholeView, np.ndarray, np.ndarray], bool] | None = None,
                  missed_max: float | None = None) -> tuple[np.ndarray, _PinholeView] | None:
    """A perspective start from the tracks alone: the camera of :func:`search_camera` on
    :data:`SEARCH_FRAMES` frames spread over the sequence, then every frame's joints under it: IK from
    many seeds (:func:`_multi_seed_ik`) and along the sequence warm-started from the previous frames
    (:func:`chainspace.robot.starts._sequential_ik`), joined into one continuous path
    (:func:`_smooth_path`, noise from :func:`chainspace.robot.uncertainty.track_jitter`). Returns (q (F, nq), the
    camera of all F frames), or None when no candidate camera sees the robot in front of it, or when under the
    searched camera every seed misses more than ``missed_max`` of the frames, if given (:data:`MOST_MISSED`).

    tracks (F, J, 2) undistorted, in square pixels (K's fx for both axes); free (F, nv) the directions
    each frame may move; gauge (nv,) the joints a static camera sees only relative to frame 0; skip, if
    given, a test of the searched camera, its search frames' joints q (n, nq) and those frames (n,):
    True returns None before every frame's IK (a view the caller has already:
    :func:`chainspace.robot.perspective._same_view`)."""
    frames = _search_frames(w)
    if frames is None:
        return None
    found = search_camera(robot, tracks, w, free, K, frames)
    if found is None or skip is not None and skip(found[1], found[2], frames):
        return None
    return _continued(robot, tracks, w, free, gauge, found[1], missed_max)


def pinhole_starts(robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, free: np.ndarray,
                   gauge: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, _PinholeView]]:
    """:func:`pinhole_start` from every distinct camera of the search (:func:`search_cameras`), best
    first: [(q (F, nq), camera)]."""
    frames = _search_frames(w)
    if frames is None:
        return []
    found = [_continued(robot, tracks, w, free, gauge, view, None)
             for _, view, _ in search_cameras(robot, tracks, w, free, K, frames)]
    return [f for f in found if f is not None]


def _search_frames(w: np.ndarray) -> np.ndarray | None:
    """:data:`SEARCH_FRAMES` frames spread over those with three points or more seen (None: under two)."""
    good = np.flatnonzero((w > 0).sum(1) >= 3)
    if len(good) < 2:
        return None
    return good[np.unique(np.linspace(0, len(good) - 1, SEARCH_FRAMES).round().astype(int))]


def _continued(robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, free: np.ndarray, gauge: np.ndarray,
               found: _PinholeView, missed_max: float | None) -> tuple[np.ndarray, _PinholeView] | None:
    """Every frame's joints under the searched camera ``found``, as :func:`pinhole_start` makes them."""
    F = len(tracks)
    view = _PinholeView(found.R, found.t, found.f, found.c, np.zeros(F, int))
    uz = np.nan_to_num(tracks)
    qs, err = _multi_seed_ik(robot, uz, w, view, free)
    jitter = track_jitter(tracks, w)
    sigma2 = (jitter if np.isfinite(jitter) else 1.0) ** 2
    # frames that no seed fits get many more seeds (the milling arm at close range: 20 frames at
    # 100 times the noise with 11 seeds, at the noise with 103), their best kept in place of the first.
    # Where the seeds miss more than ``missed_max`` of the frames, the camera is taken to be wrong: no start
    missed = err.min(1) > RETRY_ABOVE_NOISE * 2 * sigma2 * np.maximum((w > 0).sum(1), 1)
    if missed_max is not None and missed.mean() > missed_max:
        return None
    bad = np.flatnonzero(missed)
    if len(bad):
        more_q, more_err = _multi_seed_ik(robot, uz[bad], w[bad], view.take(bad), free[bad], RETRY_SEEDS, seed=1)
        keep = np.argsort(more_err, axis=1)[:, : err.shape[1]]
        qs[bad] = np.take_along_axis(more_q, keep[..., None], 1)
        err[bad] = np.take_along_axis(more_err, keep, 1)
    # with the path warm-started along the sequence as one more solution per frame
    q_warm = _sequential_ik(robot, uz, w, view, free, _best_of(qs, err)[0], gauge)
    rn = np.linalg.norm(view.apply(robot.positions(q_warm))[0] - uz, axis=-1)
    qs = np.concatenate([qs, q_warm[:, None]], 1)
    err = np.concatenate([err, (w * rn ** 2).sum(1)[:, None]], 1)
    q = _smooth_path(robot, qs, err, 2 * sigma2)
    return _bridged(robot, q, uz, w, view, free, RETRY_ABOVE_NOISE * 2 * sigma2), view
