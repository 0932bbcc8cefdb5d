"""The perspective refinement of a robot fit: one static pinhole camera (known intrinsics, or the
focal length estimated) fitted with the joint angles on the reprojection error in pixels, started from
the weak-perspective fit's winner and its mirror/flip alternatives (see :mod:`chainspace.robot.fit`),
each also turned a quarter, a half and three quarters about the first joint's axis
(:func:`chainspace.robot.starts._base_turns`: the weak camera's guess of how far round that axis it
stands can be wrong), each camera from the weak camera's pose and, with K known, from PnP on the
start's points (:func:`_pnp_camera`); every start goes through that camera stage (a camera stage that
ends with the robot behind its camera continues from the exact mirror twin in front,
:func:`chainspace.robot.candidates._pinhole_twin`), and the winner, the others that fit best there
(:data:`MAX_STARTS`) and the best turned start are refined in full, each motion once (:func:`_turned_copy`:
a turned start often comes back onto its original); fits with points behind the camera are dropped
(:func:`_in_front`). The winner's mirror image, facing the camera as it does (its twin
under weak perspective), and the winner turned about the first joint's axis with the camera turned to
match (:func:`chainspace.robot.candidates._turned_twins`: only the base's points off that axis tell
them apart) are refitted too where a plain fit of them ties: ties perspective may not settle, which no
start need reach.
Perspective then decides the depth mirrors the weak fit left open: under the winner's camera the
other starts' branches beyond each joint are tried on the winner's arm (:func:`_grafted`). Last, the
other minima near the winner along what the tracks fix least: its path moved on windows
(:func:`_weak_windows`), its loosest joints turned whole (:func:`_loose_turns`), and its wrist's exact
twins (:func:`_wrist_twins_of`), of which the tie policy keeps the nearest rest
(:func:`_nearest_rest_of_exact`). The winner's standard deviations and alternatives: :func:`_trust`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..progress import stage, stage_steps
from .kinematics import RobotKinematics, _rest_distance, _wrapped
from .observability import _hold_with_prior, _structural
from .compiled import map_tasks
from .solver import _huber, _noise_sigma, _normal_equations, _sequence_lm, _smooth_lm, \
    _smoothed_objective, acceleration_prior, jerk_prior
from .selection import under_jerk_prior
from .views import _PinholeView, _camera_view, _pinhole_from_weak, turn_between_deg
from .candidates import TIE_VARIANCES, _motion_distance, _pinhole_twin, _same_motion, _static_line_starts, \
    _turned_twins, _view_moved_with, _viterbi_reanchored
from .starts import _base_turns

# a perspective fit must beat weak perspective's by this many noise variances (squared residuals, a
# likelihood-ratio test, as for the ties of fit.py) to count as measured perspective
LR_MARGIN = 25.0
# the focal length counts as measured when its standard deviation is below this fraction of it
FOCAL_REL_STD = 0.25
# weak-perspective starts refined in full: the weak fit's winner and those of the others that fit best
# after the camera stage. The weak fit's order says nothing about perspective: its mirror and flip
# twins tie there. The Panda from above (full ranges, seed 0): of six distinct starts, the first three
# (then the only ones refined) were 40-125 degrees off on joints 1-5; the fourth, 5-20 degrees off, is
# in the true motion's basin, 340 noise variances below the reported one's, which was reported
# observable, 230 mm off
MAX_STARTS = 3
# the camera is also searched without weak perspective (:func:`_searched_starts`) when the best fit from
# the weak starts leaves squared residuals above this many times what the tracks' jitter allows: the
# milling arm at close range (nearest point 0.3 m from a 90-degree lens, 300 frames) ended at 8 times,
# with its wrist on a wrong path; a fit at the noise is near 1 (chi-square over thousands of residuals).
# It is also searched when the best fit beats weak perspective's by more than LR_MARGIN noise variances:
# perspective is then measurable, and the weak starts may all lie in another motion's basin
SEARCH_ABOVE_NOISE = 2.0
# a searched camera this close to the winner's (rotation, and depth of the robot's root as a fraction)
# is the winner's own view: refining it would only find the winner again (:func:`_same_view`). Seen (K
# known): the searches that found the winner's camera again were 0.2-1.1 degrees from it (the milling
# arm, 100 frames; the double pendulum, 30 frames, seeds 7 and 10), the others 13 degrees or more
SAME_VIEW_DEG = 10.0
SAME_VIEW_DEPTH = 0.05
# two starts of the perspective fit whose camera stages end this close (radians on every joint but the gauge
# joint's turn; relative cost) are one start (:func:`_turned_copy`). Seen: 2e-8 rad and 2e-8 of the cost
# between the milling arm's winner and its three turns (300 frames, K known)
SAME_START_RAD = 1e-6
# two fits whose residuals agree this closely (in noise deviations) at every seen point put the tracked
# points in the same place: exact twins (:func:`_nearest_rest_of_exact`). Seen: 1e-12 for the milling
# arm's wrist twins (noise-free), 0.3 for two distinct minima of the Panda (1 px noise)
EXACT_TWIN_SIGMA = 1e-3
# the winner's mirror image is tried as a start where the robot can take it to within this fraction of its
# reach at every point: a nearly symmetric arm's is a start as good as an exact one's. The Kinova Gen2
# (its links 5 mm off the plane of symmetry: 0.4 % of its reach) from above, full ranges, seed 31: the
# fit was the true motion's near mirror image, joints 2 and 3 47 and 21 degrees off, reported observable;
# the true motion's basin, which the near mirror leads to, lies about 150 noise variances lower
NEAR_MIRROR = 0.01


def _robust(rn: np.ndarray, w: np.ndarray, delta: float | None) -> float:
    return float((w * _huber(rn, delta)[0]).sum())


def _noise_variance(fit: dict, w: np.ndarray) -> float:
    """The pixel noise variance (px^2) a fit's residuals measure, at least its start's image-size floor
    squared: the unit of the tie tolerances."""
    return max(_noise_sigma(fit["rn"], w), fit["start"]["px_floor"]) ** 2


def _residual_variance(fit: dict, n_obs: int) -> float:
    """The residual variance (px^2) of a fit's squared residuals over its n_obs observed coordinates, less
    the static camera's 7 parameters: the unit of the likelihood-ratio tests."""
    return max(fit["sse"] / max(n_obs - 7, 1), 1e-12)


def _in_front(fit: dict) -> bool:
    """Whether every point of a perspective fit lies in front of its camera (positive depth)."""
    return bool((fit["view"].apply(fit["pos"])[1][..., 2] > 0).all())


def _pnp_camera(x: np.ndarray, tracks: np.ndarray, w: np.ndarray, f: float, c: np.ndarray) -> _PinholeView | None:
    """The pinhole camera of focal f, principal point c that best sees the points x (F, J, 3, base frame)
    on the tracks (F, J, 2, square pixels), all frames' points pooled: OpenCV's iterative PnP (a DLT
    start, then Levenberg-Marquardt). None when it fails or puts the points behind the camera.

    Why a second camera start beside the weak camera's pose: a small robot near the camera (strong
    perspective) makes the weak fit's motion tens of degrees off, and the weak camera's rotation then
    starts the perspective fit in the basin of another motion. The double pendulum at 0.3 m (seed 0,
    from above): from the weak camera, squared residuals 476 and 239 px^2 from the weak fit's starts;
    from PnP on the same starts' points, 158.6, the true motion's own minimum."""
    import cv2

    seen = (w > 0) & np.isfinite(x).all(-1) & np.isfinite(tracks).all(-1)
    if seen.sum() < 6:
        return None
    K = np.array([[f, 0.0, c[0]], [0.0, f, c[1]], [0.0, 0.0, 1.0]])
    points, pixels = x[seen].astype(np.float64), tracks[seen].astype(np.float64)
    try:
        # SQPnP: a global minimum in front of the camera; the iterative (DLT-started) solver lands on the
        # twin behind it when the points are nearly coplanar (the double pendulum: 5 of 8 seeds, given the
        # true points)
        ok, rv, tv = cv2.solvePnP(points, pixels, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if ok:
            ok, rv, tv = cv2.solvePnP(points, pixels, K, None, rv, tv, True, flags=cv2.SOLVEPNP_ITERATIVE)
    except cv2.error:
        return None
    if not ok or not (np.isfinite(rv).all() and np.isfinite(tv).all()):
        return None
    R = cv2.Rodrigues(rv)[0]
    if (points @ R[2] + tv[2, 0] <= 0).any():  # see _in_front
        return None
    return _PinholeView(R[None], tv.reshape(1, 3), float(f), np.asarray(c, float), np.zeros(len(x), int), False)


def _searched_starts(robot: RobotKinematics, best: dict, tracks: np.ndarray, w: np.ndarray, st: dict,
                     K: np.ndarray | None, n_obs: int, weak_sse: float) -> list[tuple[np.ndarray, _PinholeView]]:
    """Starts owing nothing to weak perspective (:func:`chainspace.robot.pinhole_start.pinhole_start`:
    the camera searched on a few frames, every frame's joints by IK under it), when the best fit from
    the weak starts leaves squared residuals above :data:`SEARCH_ABOVE_NOISE` times what the tracks' own
    jitter (:func:`chainspace.robot.uncertainty.track_jitter`; on exact tracks, a twentieth of the weak
    fit's image-size tolerance ``px_floor``) allows, or beats weak perspective's squared residuals
    ``weak_sse`` by more than :data:`LR_MARGIN` jitter variances; else none, and none where the best fit
    is not poor and the searched camera is its own (:func:`_same_view`) or one under which the IK's seeds
    miss most frames (:data:`chainspace.robot.pinhole_start.MOST_MISSED`). With the focal unknown the
    search uses the best fit's. Returns [(q (F, nq), camera)] for the refinement: where the best fit is
    poor, one from every distinct camera the search refined
    (:func:`chainspace.robot.pinhole_start.pinhole_starts`), else one from its best camera.

    Why every camera where the fit is poor: on the search's few frames a redundant arm's joints can fit a
    wrong camera better than the true one, and only the motion prior on every frame tells them apart. The
    xArm7 from above (full ranges, pinhole, 30 frames, seed 44): the winner's joint1 53 degrees off and
    reported seen; on the six frames the best camera fits at 0.78 px^2 a point and the true one at 1.62;
    the start from the search's fifth camera (4.37) ends 360 noise variances below the winner.

    Why only then: where the weak starts serve (far views) the fit is at the noise already and no
    better than weak perspective's, and the search costs seconds (the milling arm at close range, 300
    frames: 9-12 s of CPU against 211 s for the perspective refinement of the weak starts).
    Why also where perspective is measurable: the weak fit's motion is then no longer the pinhole's, and
    every weak start can lie in another motion's basin. The double pendulum (one moving point, on
    joint1's circle; synthesize's pinhole camera, K known, 30 frames, seed 39): joint1 60 degrees RMS
    off from the weak starts, unflagged (:func:`_pinhole_gauge` applied); 0.2 degrees from this start."""
    from .pinhole_start import MOST_MISSED, pinhole_start, pinhole_starts
    from .uncertainty import track_jitter

    jitter = track_jitter(tracks, w)
    # exact tracks: a twentieth of the weak fit's image-size tolerance, as its ties have it
    noise = max(jitter, 0.05 * st["px_floor"])
    if not np.isfinite(jitter):
        return []
    poor = best["sse"] > SEARCH_ABOVE_NOISE * n_obs * noise ** 2
    measurable = weak_sse - best["sse"] > LR_MARGIN * noise ** 2
    if not (poor or measurable):
        return []
    view = best["view"]
    K = view.K if K is None else K
    if poor:
        # none skipped: the winner's camera can be right and its path wrong, and the search's per-frame IK
        # under that camera is then what mends the path (the milling arm at close range, K known, 300
        # frames: the searched camera passed for the winner's; skipped, joints a3, a4 and a6 ended 1.0,
        # 6.8 and 12.9 degrees RMS off, against 0.08, 0.33 and 0.27 with the searched start refined)
        found = pinhole_starts(robot, tracks, w, st["free"], st["gauge"], K)
    else:
        # the winner's own camera found again: refining its start would only find the winner again
        same = (lambda pv, q, frames: _same_view(robot, pv, view) or _same_view(
            robot, pv, _gauge_turned(robot, best["q"][frames], view, st["gauge"], q)))
        one = pinhole_start(robot, tracks, w, st["free"], st["gauge"], K, same, MOST_MISSED)
        found = [] if one is None else [one]
    return [(q, replace(pv, fit_focal=view.fit_focal, fit_centre=view.fit_centre)) for q, pv in found]


def _same_view(robot: RobotKinematics, a: _PinholeView, b: _PinholeView) -> bool:
    """Whether two static pinhole cameras see the robot alike: rotations within :data:`SAME_VIEW_DEG`
    of each other and the robot's root at depths within :data:`SAME_VIEW_DEPTH` of each other.

    Why: the searched start (:func:`_searched_starts`) costs IK in every frame and a full refinement;
    where its camera is the winner's own, they only find the winner again (the milling arm, K known,
    100 frames, seed 0: the search's camera 0.2 degrees from the winner's, at the same depth)."""
    if turn_between_deg(a.R[0], b.R[0]) > SAME_VIEW_DEG:
        return False
    root = robot.positions(robot.q_rest)[0, robot.chain.joint_index(robot.chain.root)]
    za, zb = a.R[0, 2] @ root + a.t[0, 2], b.R[0, 2] @ root + b.t[0, 2]
    return bool(abs(za - zb) <= SAME_VIEW_DEPTH * max(abs(zb), 1e-12))


def _gauge_turned(robot: RobotKinematics, q: np.ndarray, view: _PinholeView, gauge: np.ndarray,
                  q_other: np.ndarray) -> _PinholeView:
    """The camera ``view`` of the motion q (n, nq) turned about the first joint's axis
    (:func:`chainspace.robot.starts._base_turns`) as far as the gauge joint of q_other (n, nq) differs
    from q's in the first frame, so that the turned motion projects as q did: the camera of q_other's
    view of the same motion. ``view`` itself where the gauge (nv,) holds no such joint.

    Why: a gauge joint (a change of view imitates it) is held in frame 0 at the value of its start, and
    a start turned about the first joint's axis holds it turned, its camera turned to match: the same
    view, a quarter turn apart. The UR10, K known, 100 frames, seed 0: the winner's joint1 held at -90
    degrees in frame 0, the searched start's at 0, their cameras 89.7 degrees apart at the same depth;
    the searched start refined to the winner's objective."""
    from .views import similarity_align

    if gauge.sum() != 1:
        return view
    turn = float(robot.wrap_angles(robot.angles(q_other[:1]) - robot.angles(q[:1]))[0, gauge][0])
    turned = _base_turns(robot, q, (turn,))
    if not turned:
        return view
    if np.abs(robot.wrap_angles(robot.angles(turned[0][:1]) - robot.angles(q_other[:1]))[0, gauge]).max() > 1e-6:
        return view  # the joint turned is not the gauge joint
    pos, pt = robot.positions(q), robot.positions(turned[0])
    moved = np.linalg.norm(pt - pos, axis=-1) > 1e-9 * robot.reach()
    if not moved.any():
        return view
    _, A, b = similarity_align(np.where(moved[..., None], pos, np.nan), np.where(moved[..., None], pt, np.nan),
                               scale=False)  # the turn, x_t = A x + b (as candidates._turned_twins)
    R = view.R[0] @ A.T
    return replace(view, R=R[None], t=(view.t[0] - R @ b)[None])


def _turned_copy(robot: RobotKinematics, a: tuple, b: tuple, gauge: np.ndarray) -> bool:
    """Whether the camera stage's results a and b (``camera_start``'s (cost, camera, q, ...)) are one
    motion: b's q (F, nq) a's turned about the gauge joints (nv,) by one angle in every frame (its
    camera turned to match) within :data:`SAME_START_RAD`, at a's cost to within a relative
    :data:`SAME_START_RAD`. Not :func:`chainspace.robot.candidates._same_motion`'s tolerance: a start
    is skipped only where the camera stage put it on another's motion to rounding."""
    return bool(_motion_distance(robot, b[2], a[2], gauge) < SAME_START_RAD and
                abs(b[0] - a[0]) <= SAME_START_RAD * max(abs(a[0]), 1e-12))


def _pinhole_gauge(robot: RobotKinematics, st: dict, w: np.ndarray, unseen: np.ndarray) -> dict:
    """The weak-perspective start ``st`` held as a static pinhole camera sees it: a joint held at rest
    in frame 0 (seen only relative to it) only where it is a structural gauge
    (:func:`chainspace.robot.observability._structural`: a change of view imitates it at every
    configuration), with ``q``, ``free``, ``free_prior`` and ``gauge`` recomputed so.

    Why: the weak fit also holds a joint that its configuration makes a gauge (the 3D fit's, and its
    affine camera's), and a static pinhole camera sees it. The double pendulum (its base point 35 mm off
    joint1's axis; synthesize's pinhole camera, K known, 30 frames): joint1 held in frame 0 could not
    be corrected there, and seeds 10 and 27 ended 6.5 and 62 degrees RMS off (relative to frame 0),
    unflagged; held only where structural, 0.7 (flagged: a tie) and 0.3 degrees."""
    gauge = _structural(robot, w)[1] & ~st["blind"]
    q, free, free_prior = _hold_with_prior(robot, st["q"], st["blind"], gauge, False, unseen)
    if (gauge == st["gauge"]).all() and (free == st["free"]).all() and (free_prior == st["free_prior"]).all():
        return st  # held as the pinhole holds it already (a base point on the first axis: the arms)
    return dict(st, q=q, free=free, free_prior=free_prior, gauge=gauge)


def _camera_covariance(robot: RobotKinematics, q: np.ndarray, view: _PinholeView, tracks: np.ndarray,
                       w: np.ndarray, free: np.ndarray, delta: float | None, sigma2: float) -> np.ndarray:
    """Gauss-Newton covariance of the camera parameters (rotation vector, translation[, log f][, c]) with the
    joint angles of every frame eliminated (Schur complement; the motion prior left out, so the
    spread is an upper bound of what the smoothed fit knows), scaled by the residual variance sigma2."""
    pos, jac = robot.jacobians(q)
    pred, y = view.apply(pos)
    res = pred - np.nan_to_num(tracks)
    ww = w * _huber(np.linalg.norm(res, axis=-1), delta)[1]
    Hqq, Hqc, gq, Hcc, gc = _normal_equations(view, jac, y, res, ww, free, np.ones(view.n_params, bool))
    nv = robot.nv
    Hq = Hqq + (~free)[:, :, None] * np.eye(nv) + 1e-12 * np.eye(nv)
    schur = Hcc[0] - np.einsum("fvc,fvd->cd", Hqc, np.linalg.solve(Hq, Hqc))
    try:  # not pinv: a direction the tracks do not fix must come out with a huge variance, not zero
        scale = np.sqrt(np.maximum(np.diag(schur), 1e-300))
        cov = np.linalg.inv(schur / np.outer(scale, scale)) / np.outer(scale, scale)
    except np.linalg.LinAlgError:
        return np.full(schur.shape, np.inf)
    return sigma2 * cov


def refine_perspective(robot: RobotKinematics, starts: list[dict], tracks: np.ndarray, w: np.ndarray,
                       K: np.ndarray | None, image_size, accel_std: float | None, fps: float,
                       speed_decay_s: float | None, unseen: np.ndarray, max_iter: int, tol: float,
                       weak_sse: float, smooth: bool, search_ties: bool = False, weak_fits: bool = False,
                       jerk_std: float | None = None) -> dict:
    """Fit the pinhole camera and joint angles from the weak-perspective starts (every one through the
    camera stage; the first, the weak fit's winner, and the others of lowest cost there refined in full,
    :data:`MAX_STARTS` in all), and from the best graft of the others onto the winner
    (:func:`_grafted`); keep the lowest objective. With the focal length unknown and ``weak_fits`` (the weak
    fit's typical point within what the tracks' jitter allows: ``uncertainty.camera_misfit``), the first is
    refined before the others are screened, and where its fit measures no perspective
    (:func:`_measured_perspective`) it is returned, not measured, without them: a far camera's footage
    (the UR10, 300 frames, weak camera: 1.8 -> 1.19 times the weak fit's time). Not where the weak fit
    misfits: the UR10 filmed close (``bench_no_camera.py``, seed 2, misfit 5.1) measured no perspective from
    its weak winner alone and perspective from the other starts.

    starts: dicts with q (F, nq), view (weak :class:`_View`), free, free_prior (F, nv), delta (Huber).
    K (3, 3) known intrinsics (tracks already undistorted), or None with ``image_size`` (w, h): the
    focal length is fitted too (principal point at the image centre); neither (``image_size`` None):
    the principal point is fitted as well, from the centre of the tracks' extent. Returns a dict with the winner's
    q, view, rn, pos, objective, sse, the other starts' objectives, the focal and its standard
    deviation (estimated focal only), and ``measured`` (False: perspective not measurable; see
    ``reason``). ``jerk_std``: the fits finished under the jerk prior (:meth:`_under_jerk_prior`), or None.
    """
    return PerspectiveRefinement(robot, tracks, w, K, image_size, accel_std, fps, speed_decay_s, unseen, max_iter,
                                 tol, smooth, jerk_std).run(starts, weak_sse, search_ties, weak_fits)


class PerspectiveRefinement:
    """The perspective fit of ``robot`` to ``tracks`` (F, J, 2) px, weights ``w`` (F, J), through one static
    pinhole camera: ``K`` known, or None (the focal fitted; with ``image_size`` None the principal point
    too). Holds the fits made so far (``fits``, best first); :meth:`run` makes them from the weak starts."""

    def __init__(self, robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, K: np.ndarray | None, image_size,
                 accel_std: float | None, fps: float, speed_decay_s: float | None, unseen: np.ndarray,
                 max_iter: int, tol: float, smooth: bool, jerk_std: float | None = None):
        self.robot, self.w, self.unseen, self.max_iter, self.tol = robot, w, unseen, max_iter, tol
        self.accel_std, self.fps, self.speed_decay_s, self.smooth = accel_std, fps, speed_decay_s, smooth
        self.jerk_std = jerk_std
        self.K = None if K is None else np.asarray(K, float)
        self.fit_focal = K is None
        self.fit_centre = self.fit_focal and image_size is None
        if self.fit_centre:  # no image: the principal point starts at the centre of the tracks and is fitted too
            seen = (w > 0) & np.isfinite(tracks).all(-1)
            lo, hi = tracks[seen].min(0), tracks[seen].max(0)
            self.c = 0.5 * (lo + hi)
            # focal starts as for an image twice the tracks' extent (a robot over half the frame); from the
            # extent alone, so that shifting every track changes nothing but the principal point
            wpx = 2.0 * float((hi - lo).max())
        elif self.fit_focal:
            wpx, hpx = (float(v) for v in image_size)
            self.c = np.array([wpx / 2, hpx / 2])
        if self.fit_focal:
            self.f_inits = [wpx * k for k in (0.5, 0.7, 1.0, 1.4, 2.0, 4.0)]
            self.aspect = 1.0
        else:
            self.c = self.K[:2, 2].copy()
            self.f_inits = [float(self.K[0, 0])]
            self.aspect = float(self.K[0, 0] / self.K[1, 1])
        # square pixels for the solver: rows scaled to the focal of the columns
        self.tr = tracks.copy()
        self.tr[..., 1] = self.c[1] + (self.tr[..., 1] - self.c[1]) * self.aspect
        self.n_obs = 2 * int((w > 0).sum())
        self.fits: list[dict] = []

    def contend(self, new: list[dict]) -> None:
        """New fits join the others, ordered by objective. A pinhole projects y and -y alike: a fit with the
        robot behind its camera (the true one's twin through the camera centre, mirrored about the robot's
        symmetry plane) fits exactly as well and is no camera, so it is dropped while one in front is left."""
        fits = self.fits
        fits.extend(new)
        fits[:] = [r for r in fits if _in_front(r)] or fits
        fits.sort(key=lambda r: r["objective"])

    def finish(self, q: np.ndarray, pv: _PinholeView, st: dict, n_iter: int) -> list[dict]:
        """LM on everything from (q, pv), the branch of every frame re-chosen under this camera, then
        smoothed: the fits of one start, its own first, then the paths the branch choice left that fit
        the tracks within the tie tolerance (smoothed alike: a tie is then reported, not hidden).

        Why every descent counts: the branch choice was kept only when it lowered the objective by 1 %,
        a rounding guard that grows with the sequence. The xArm7, focal unknown, 300 frames (seed 0):
        the wrist's path re-chosen on frames 236-281 lowered the robust objective by 6 px^2 (7 noise
        variances, 0.2 %) and was thrown away; the path kept smoothed to joint6 5.9 degrees RMS off
        (21.8 at most), 17 noise variances above the true motion's minimum, which the re-chosen path
        smooths to (joint6 1.2 degrees), and nothing was flagged."""
        robot, tr, w, max_iter, tol = self.robot, self.tr, self.w, self.max_iter, self.tol
        delta, ones = st["delta"], np.ones(pv.n_params, bool)
        out = _sequence_lm(robot, q, tr, w, pv, st["free"], ones, max_iter, tol, delta)
        left = []
        for _ in range(2):  # the branch of every frame, chosen for the whole sequence under this camera
            sig = max(_noise_sigma(out[2], w), st["px_floor"])
            q_fix, view_fix = _viterbi_reanchored(robot, out[0], tr, w, out[1], st["free"], sig, st["gauge"], False,
                                                  st["blind"], self.unseen)
            if np.abs(_wrapped(robot, q_fix - out[0])).max() < 0.05:
                break
            new = _sequence_lm(robot, q_fix, tr, w, view_fix, st["free"], ones, max_iter, tol, delta)
            gain = _robust(out[2], w, delta) - _robust(new[2], w, delta)
            if gain <= sig ** 2:  # no descent beyond a noise variance (exact twins: rounding)
                break
            if gain <= TIE_VARIANCES * sig ** 2:
                left.append(out)
            out = new
        prior = self._prior(out)
        fitted = []
        for o in [out] + left:  # one prior for all: their objectives are compared
            objective = _robust(o[2], w, delta)
            if prior is not None:
                o = _smooth_lm(robot, robot.continuous(o[0]), tr, w, o[1], st["free_prior"], ones, max_iter, tol,
                               delta, prior)
                objective = _smoothed_objective(prior, robot.angles(o[0]), o[2], w, delta)
            fitted.append(dict(q=o[0], view=o[1], rn=o[2], pos=o[3], conv=o[4], n_iter=o[5] + n_iter,
                               objective=objective, sse=float((w * o[2] ** 2).sum()), free=st["free"], delta=delta,
                               prior=prior, start=st))
        return fitted

    def _prior(self, out: tuple):
        """The motion prior for a fit whose plain solve is ``out`` (its noise sets the weight), or None."""
        if not (self.smooth and self.accel_std is not None and len(self.tr) >= 3):
            return None
        sigma = max(_noise_sigma(out[2], self.w), 1e-3)
        return acceleration_prior(self.unseen, sigma, self.accel_std, self.fps, self.speed_decay_s)

    def camera_start(self, st: dict, focals: list[float], frames: np.ndarray | None = None) -> tuple:
        """The camera alone from the start's pose (the weak camera's, and with K known PnP's), then
        per-frame IK under it, alternated (the focal held): (cost, camera, q, focal, iterations) of the
        camera start and focal that fit best. The weak start's motion can be far off under perspective,
        so the focal and the camera are chosen after the IK. ``frames``: on those frames only (the
        camera and q then for them)."""
        robot, tr, w = self.robot, self.tr, self.w
        q0, delta, free, weak = st["q"], st["delta"], st["free"], st["view"]
        if frames is not None:
            tr, w, q0, free, weak = tr[frames], w[frames], q0[frames], free[frames], weak.take(frames)
        pos0 = robot.positions(q0)
        none_free = np.zeros_like(free)
        ones_k, n_iter, best_cam = np.ones(6, bool), 0, None
        for f0 in focals:
            pnp = None if self.fit_focal else _pnp_camera(pos0, tr, w, f0, self.c)
            # a turned start: PnP's camera alone where there is one (its weak camera is re-fitted, not measured)
            cams = [pnp] if "turn_of" in st and pnp is not None else \
                [_pinhole_from_weak(weak, pos0, f0, self.c, False), pnp]
            for pv in cams:
                if pv is None:
                    continue
                pv = _sequence_lm(robot, q0, tr, w, pv, none_free, ones_k, 30, 1e-10, delta)[1]
                q = q0
                for _ in range(3):
                    q, _, _, _, _, it = _sequence_lm(robot, q, tr, w, pv, free, ~ones_k, 10, 1e-8, None)
                    pv = _sequence_lm(robot, q, tr, w, pv, none_free, ones_k, 10, 1e-10, delta)[1]
                    n_iter += it
                cost = _robust(np.linalg.norm(pv.apply(robot.positions(q))[0] - np.nan_to_num(tr), axis=-1), w, delta)
                if best_cam is None or cost < best_cam[0]:
                    best_cam = (cost, pv, q, f0)
        cost, pv, q, f0 = best_cam
        # a pinhole projects y and -y alike: a camera with the robot behind it is no camera, but the mirror
        # image of its motion, in front, is an exact twin (_pinhole_twin; a mirror-symmetric robot)
        twin = None if _in_front(dict(view=pv, pos=robot.positions(q))) else _pinhole_twin(robot, q, pv, free)
        return (cost, pv, q, f0, n_iter) if twin is None else (cost, twin[1], twin[0], f0, n_iter)

    def refine_in_full(self, st: dict, screened: tuple) -> list[dict]:
        """A start refined in full from its camera stage's result ``screened`` (:meth:`camera_start`): with
        the focal unknown, per-frame IK alternated with the camera and its focal first; then :meth:`finish`."""
        robot, tr, w = self.robot, self.tr, self.w
        _, pv, q, _, n_iter = screened
        none_free = np.zeros_like(st["free"])
        pv = replace(pv, fit_focal=self.fit_focal, fit_centre=self.fit_centre)
        if self.fit_focal:
            ones = np.ones(pv.n_params, bool)
            for _ in range(3):  # per-frame IK under the camera, alternated with the camera and its focal
                q, _, _, _, _, it = _sequence_lm(robot, q, tr, w, pv, st["free"], ~ones, 10, 1e-8, None)
                pv = _sequence_lm(robot, q, tr, w, pv, none_free, ones, 10, 1e-10, st["delta"])[1]
                n_iter += it
        return self.finish(q, pv, st, n_iter)

    def tied(self, out: tuple, lead: dict, var0: float) -> bool:
        """Whether a plain fit (:func:`_sequence_lm`'s returns) ends within the tie tolerance of the lead, or
        below it."""
        return _robust(out[2], self.w, lead["delta"]) - _robust(lead["rn"], self.w, lead["delta"]) <= \
            TIE_VARIANCES * var0

    def mirror_start(self, q_m: np.ndarray, lead: dict) -> tuple:
        """A plain fit of the mirror image q_m of the lead's motion from a camera of its own (the camera stage
        of a start): where perspective is strong, the mirrored camera (:func:`_pinhole_twin`) is too far
        from the mirror image's to lead to its basin. The Kinova from above (full ranges, seed 31), the fit
        the true motion's near mirror image: from the mirrored camera 1644 px^2, from its own 640, the
        lead 798."""
        st = dict(lead["start"], q=q_m, view=_camera_view(self.robot.positions(q_m), self.tr, self.w, False))
        _, pv, q, _, _ = self.camera_start(st, [float(lead["view"].f)])
        pv = replace(pv, fit_focal=self.fit_focal, fit_centre=self.fit_centre)
        return _sequence_lm(self.robot, q, self.tr, self.w, pv, lead["free"], np.ones(pv.n_params, bool),
                            self.max_iter, self.tol, lead["delta"])

    # ---- the whole fit
    def run(self, starts: list[dict], weak_sse: float, search_ties: bool, weak_fits: bool) -> dict:
        """:func:`refine_perspective`: the starts screened and the best refined (:meth:`_from_starts`, which
        may return early where the focal is unknown and the first start measures no perspective), the
        other minima searched (:meth:`_other_minima`), then the winner chosen and assessed."""
        robot, w = self.robot, self.w
        starts = [_pinhole_gauge(robot, st, w, self.unseen) for st in starts]
        early = self._from_starts(starts, weak_sse, weak_fits)
        if early is not None:
            return early
        fits = self.fits
        turned = self._other_minima(starts, weak_sse)
        clear = fits[0]["objective"] - TIE_VARIANCES * _noise_variance(fits[0], w)
        self.contend([r for r in turned if r["objective"] < clear])
        self.contend([r for r in _wrist_twins_of(robot, fits[0], self.tr, w)
                      if not any(_same_motion(robot, r["q"], o["q"]) for o in fits)])
        best = _nearest_rest_of_exact(robot, fits, w)
        fits[:] = [best] + [r for r in fits if r is not best] + [r for r in turned if r["objective"] >= clear]
        var = _residual_variance(best, self.n_obs)
        # (the weak fit's mirror/flip alternatives that perspective settles or not: the windows', turns' and wrist
        # twins' own ties are _trust's, and so are the exact twins that other starts ended on: the Kinova from
        # below, full ranges, seed 44, was said to tie with its mirror image where its only unsettled
        # alternatives were its wrist's exact twins, flagged on the wrist's joints)
        twin_of_best = _exact_twin_of(best, w)
        relative = best["start"]["gauge"] & ~best["start"]["blind"]
        others = [r for r in fits if r is not best and not any(r.get(k) for k in ("window", "twin", "turn")) and
                  not _same_motion(robot, r["q"], best["q"], relative) and not twin_of_best(r)]
        best["settled"] = all(r["objective"] - best["objective"] > LR_MARGIN * var for r in others)
        best["n_alternatives"] = len(others)
        best["var"] = var
        best["measured"], best["reason"] = True, ""
        best["aspect"] = self.aspect
        if self.fit_focal:
            best.update(_measured_perspective(robot, best, self.tr, w, weak_sse, self.n_obs, self.fit_centre))
        if best["measured"] and best["prior"] is not None and self.jerk_std is not None and len(self.tr) > 3:
            self._under_jerk_prior(best, fits)
        if best["measured"]:  # else the weak fit is reported, with its own
            stage("robot fit, perspective: the joint angles' standard deviations and alternatives")
            best["trust"] = _trust(robot, best, fits, self.tr, w, search_ties)
        return best

    def _under_jerk_prior(self, best: dict, fits: list[dict]) -> None:
        """Every fit finished under the jerk prior (:func:`chainspace.robot.selection.under_jerk_prior`),
        in place: its motion, camera, residuals and objective; the winner's focal (and principal point)
        where they are estimated."""
        w = self.w
        prior = jerk_prior(self.unseen, max(_noise_sigma(best["rn"], w), 1e-3), self.jerk_std, self.fps,
                           self.speed_decay_s)
        starts = [(r["q"], r["view"], r["start"]["free_prior"], r["delta"]) for r in fits]
        finished = under_jerk_prior(self.robot, starts, self.tr, w, prior, self.max_iter, self.tol)
        for r, (objective, o) in zip(fits, finished):
            r.update(q=o[0], view=o[1], rn=o[2], pos=o[3], conv=o[4], n_iter=r["n_iter"] + o[5], objective=objective,
                     sse=float((w * o[2] ** 2).sum()), prior=prior)
        if "focal" in best:  # the finished camera's (its deviation, measured just before, stands)
            best["focal"] = float(best["view"].f)
            if "centre" in best:
                best["centre"] = best["view"].c.copy()

    def _from_starts(self, starts: list[dict], weak_sse: float, weak_fits: bool) -> dict | None:
        """Every start (as :func:`_pinhole_gauge` makes them; and each turned about the first joint's axis:
        the weak camera's guess of how far round it stands) through the camera stage, the first over the
        focal guesses and the others at its focal; then the weak fit's winner, the others of lowest cost
        there (MAX_STARTS in all) and the best turned start refined in full, into ``fits``. Returns the
        first start's fit where it alone settles that there is no perspective (``weak_fits`` and the focal
        unknown: :func:`refine_perspective`), else None."""
        from .uncertainty import _sample_step

        robot, w = self.robot, self.w
        n_given = len(starts)
        starts = list(starts) + [dict(st, q=q, view=_camera_view(robot.positions(q), self.tr, w, False), turn_of=st)
                                 for st in starts for q in _base_turns(robot, st["q"])]
        early = self.fit_focal and weak_fits  # the first start may settle that there is no perspective (docstring)
        step = stage_steps("robot fit, perspective: the camera from start", len(starts))
        step(0)
        screened, first = [self.camera_start(starts[0], self.f_inits)], []  # the first over the focal guesses
        chosen_f = screened[0][3] if self.fit_focal else self.f_inits[0]
        if early:
            first = self.refine_in_full(starts[0], screened[0])
            lead = min(first, key=lambda r: r["objective"])
            measured = _measured_perspective(robot, lead, self.tr, w, weak_sse, self.n_obs, self.fit_centre)
            if not measured["measured"]:
                return dict(lead, **measured)
        # the others at its focal, on a long sequence ranked on every k-th frame (as the searches sample it,
        # uncertainty._sample_step) and the kept ones put through the camera stage again on every frame: only their
        # order counts, and 20 starts on all 300 frames were 1.5 s of the xArm7's 14 s (K known, one thread)
        k_th = _sample_step(len(self.tr))
        frames = None if k_th == 1 else np.arange(0, len(self.tr), k_th)
        screened += map_tasks(robot, lambda st: self.camera_start(st, [chosen_f], frames), starts[1:],
                              lambda i: step(i + 1))
        # the turned starts compete for a slot of their own: on the xArm7 from below (full ranges, seed 0) one of
        # lower camera-stage cost pushed the true basin's start out, and the fit ended 151 degrees off
        by_cost = sorted(range(1, len(starts)), key=lambda k: screened[k][0])
        keep = [0] + [k for k in by_cost if k < n_given][:MAX_STARTS - 1] + \
            [k for k in by_cost if k >= n_given][:1]
        if frames is not None:
            for k, r in zip(keep[1:], map_tasks(robot, lambda k: self.camera_start(starts[k], [chosen_f]), keep[1:])):
                screened[k] = r
        # (a start that the camera stage brought onto one kept before it, turned about the gauge joint, is refined
        # into that one's basin: the milling arm, 300 frames, K known: all three turns of the winner's start came
        # back onto it, and the one kept ended on the winner's objective to 2e-10 after 1 s of refining; the
        # xArm7, 100 frames, on a fit 0.26 degrees from the winner's on joint5)
        keep = [k for i, k in enumerate(keep) if not any(
            _turned_copy(robot, screened[j], screened[k], starts[k]["gauge"]) for j in keep[:i])]
        step = stage_steps("robot fit, perspective: refining in full, start", len(keep))
        for r in map_tasks(robot, lambda k: first if k == 0 and early else self.refine_in_full(starts[k], screened[k]),
                           keep, step):
            self.fits += r
        self.contend([])
        return None

    def _other_minima(self, starts: list[dict], weak_sse: float) -> list[dict]:
        """Six searches around the best fit, each a step of the stage's log (a count and the time left: 3.5 s
        in the demo at 300 frames): a camera searched without weak perspective, the other ``starts``' (the
        given ones, as :meth:`_from_starts` takes them) branches grafted onto the winner, its twins, its
        turns about the base's line, its windows and its path moved towards the ends join ``fits``; its
        loosest joints turned whole are returned, for :meth:`run` to weigh."""
        robot, tr, w, fits = self.robot, self.tr, self.w, self.fits
        other = stage_steps("robot fit, perspective: other minima (a searched camera, grafts, twins, turns about the "
                            "base's line, windows and ends, turned joints), search", 6)
        other(0)
        for searched in _searched_starts(robot, fits[0], tr, w, starts[0], self.K, self.n_obs, weak_sse):
            self.contend(self.finish(*searched, starts[0], 0))  # more contenders, on the objective like the others
        # (the given starts only: a turned start's tails beyond the first joint are its original's)
        other(1)
        grafted = _grafted(robot, fits[0], [st["q"] for st in starts] + [r["q"] for r in fits[1:]], tr, w)
        if grafted is not None:
            self.contend(self.finish(grafted, fits[0]["view"], fits[0]["start"], 0))
        other(2)
        self._twins_of_lead()
        # the winner turned about the line of the base's tracked points, where no joint turns about it, with the
        # camera turned to match (candidates._static_line_starts): the camera's freedom about that line is bounded
        # only by whether the robot can make the turned motion, and no start need lie in the basin it leads to
        other(3)
        lead = fits[0]
        for r in map_tasks(robot, lambda s: self.finish(*s, lead["start"], 0), _static_line_starts(
                robot, dict(lead, gauge=lead["start"]["gauge"], var=_noise_variance(lead, w)), tr, w, TIE_VARIANCES)):
            self.contend(r)
        # the winner's path moved on windows along what the tracks fix least: minima that differ from it on a
        # window only, which no whole-sequence candidate is (a tie then reported, or a lower one the winner)
        other(4)
        lead = fits[0]
        # and moved towards the sequence's ends, where the motion prior holds it from one side only
        moved = _weak_windows(robot, lead, tr, w, self.fps) + _end_moves(robot, lead, tr, w, self.fps)
        self.contend([r for r in moved if not _same_motion(robot, r["q"], lead["q"])])
        # and its loosest joints turned whole: minima tens of degrees away along them, beyond the windows' reach.
        # A turned fit takes over only where the tracks prefer it beyond the tie tolerance; within it, the one the
        # starts reached stays and the turned one is reported as a tie (among minima within a noise variance of
        # each other, the full ranges' Panda from below, which one is lowest is the noise's choice)
        other(5)
        return [r for r in _loose_turns(robot, fits[0], tr, w) if not any(_same_motion(robot, r["q"], o["q"])
                                                                          for o in fits)]

    def _twins_of_lead(self) -> None:
        """The winner's mirror image, facing the camera as it does, the winner turned about the first joint's
        axis with the camera turned to match, and its near twins over the shoulder (:func:`_near_twin_starts`):
        its twins, which no start need reach (each refitted in full only when a plain fit of it ties with the
        winner's or beats it: a big robot's mirror twin is far off)."""
        robot, fits = self.robot, self.fits
        lead = fits[0]
        mirror = _pinhole_twin(robot, lead["q"], lead["view"], lead["free"], NEAR_MIRROR)
        var0 = _noise_variance(lead, self.w)
        twins = [(tw, tw is mirror) for tw in ([] if mirror is None else [mirror]) +
                 _turned_twins(robot, lead["q"], lead["view"]) + _near_twin_starts(robot, lead)]
        for (q_tw, v_tw), is_mirror in twins:
            if any(_same_motion(robot, q_tw, r["q"]) for r in fits):
                continue
            plain = _sequence_lm(robot, q_tw, self.tr, self.w, v_tw, lead["free"], np.ones(v_tw.n_params, bool),
                                 self.max_iter, self.tol, lead["delta"])
            if is_mirror and not self.tied(plain, lead, var0):
                plain = min(plain, self.mirror_start(q_tw, lead), key=lambda o: _robust(o[2], self.w, lead["delta"]))
            if self.tied(plain, lead, var0):
                fits += self.finish(plain[0], plain[1], lead["start"], plain[5])
        self.contend([])


def _near_twin_starts(robot: RobotKinematics, lead: dict) -> list[tuple[np.ndarray, _PinholeView]]:
    """The fit ``lead``'s near twins (:func:`chainspace.robot.uncertainty._near_twins`), each with lead's camera
    moved as the rigid motion that brings lead's points closest to the twin's moves the scene (where the
    camera's turn stands in for the first joint's): [(q, view)], starts."""
    from .uncertainty import _near_twins
    from .views import similarity_align

    pos = robot.positions(lead["q"])
    out = []
    for q_n in _near_twins(robot, lead["q"], lead["free"]):
        _, A, b = similarity_align(pos, robot.positions(q_n), scale=False)
        out.append((q_n, _view_moved_with(lead["view"], A, b)))
    return out


def _measured_perspective(robot: RobotKinematics, fit: dict, tracks: np.ndarray, w: np.ndarray, weak_sse: float,
                          n_obs: int, fit_centre: bool) -> dict:
    """Whether a fit of unknown focal length measures perspective: ``{"measured", "reason", "focal",
    "focal_std"[, "centre", "centre_std"]}``. Not measured where the focal's standard deviation
    (Gauss-Newton, the joints eliminated, scaled by the fit's residual variance) exceeds
    :data:`FOCAL_REL_STD` of it, or where the fit does not beat the weak fit's squared residuals
    ``weak_sse`` by :data:`LR_MARGIN` noise variances (a likelihood-ratio test)."""
    var = _residual_variance(fit, n_obs)
    view = fit["view"]
    cov = _camera_covariance(robot, fit["q"], view, tracks, w, fit["free"], fit["delta"], var)
    f = view.f
    std = float(f * np.sqrt(max(cov[6, 6], 0.0)))
    out = {"measured": True, "reason": "", "focal": float(f), "focal_std": std}
    if fit_centre:
        out["centre"], out["centre_std"] = view.c.copy(), np.sqrt(np.maximum(np.diag(cov)[7:9], 0.0))
    if not np.isfinite(std) or std > FOCAL_REL_STD * f:
        out["measured"] = False
        out["reason"] = (f"the focal length is not measurable from these tracks ({f:.0f} +- {std:.0f} px: no "
                         "measurable perspective)")
    elif weak_sse - fit["sse"] <= LR_MARGIN * var:
        out["measured"] = False
        out["reason"] = (f"perspective does not fit the tracks measurably better than weak perspective "
                         f"(squared residuals {fit['sse']:.4g} against {weak_sse:.4g} px^2, noise "
                         f"variance {var:.3g} px^2: no measurable perspective)")
    return out


def _nearest_rest_of_exact(robot: RobotKinematics, fits: list[dict], w: np.ndarray) -> dict:
    """Of the fits (ordered by objective) that are the lowest's exact twins, the nearest to rest (the tie
    policy's distance, :func:`chainspace.robot.kinematics._rest_distance`); the lowest where it has none.
    Exact twins as :func:`_exact_twin_of` tells them.

    Why: exact twins (a wrist's mirror image where the tracked points beyond it lie in one plane seen
    face-on) differ in objective by rounding alone, and which one rounds lower changed with the OpenCV
    build (the milling arm, K known, noise-free: 180 degrees off on the wrist with opencv 5.1, right
    with 5.0; their residuals agreed to 1e-12 of the noise), so the policy decides, the same way on
    every machine; the twin stays an alternative. Why not every fit within a noise variance: two
    distinct minima can be that close (the Panda from below, full ranges, 30 frames: 0.29 variances
    apart, residuals up to 0.32 noise deviations apart), and there the lower one is the rule
    (nearest rest chose the one 31.6 mm off, against 2.2; both report the other as a tie)."""
    exact = _exact_twin_of(fits[0], w)
    return min([r for r in fits if exact(r)],
               key=lambda r: _rest_distance(robot, r["q"], r["q"][:1], r["start"]["gauge"]).mean())


def _exact_twin_of(lead: dict, w: np.ndarray):
    """``exact(r)``: whether fit r is fit lead's exact twin: its objective within one noise variance of
    lead's, and every seen point's residual within :data:`EXACT_TWIN_SIGMA` noise deviations of lead's (the
    tracked points in the same place). Lead's noise is measured once, not per fit tested."""
    sigma = max(_noise_sigma(lead["rn"], w), lead["start"]["px_floor"])
    seen = (w > 0) & np.isfinite(lead["rn"])

    def exact(r: dict) -> bool:
        return (r["objective"] - lead["objective"] <= sigma ** 2
                and bool(np.all(np.abs(r["rn"] - lead["rn"])[seen] <= EXACT_TWIN_SIGMA * sigma)))

    return exact


def _wrist_twins_of(robot: RobotKinematics, lead: dict, tracks: np.ndarray, w: np.ndarray) -> list[dict]:
    """The fit ``lead``'s wrist Euler twins (:func:`chainspace.robot.uncertainty._wrist_twins`: every tracked
    point in place under any camera) as fits, scored as they are under lead's camera and prior, not
    refitted: an exact twin scores as lead does to rounding, and the tie policy chooses between them
    (:func:`_nearest_rest_of_exact`).

    Why: which twin the starts descend to is rounding. The milling arm, K known, noise-free (seed 5)
    came out 180 degrees off on the wrist on a fresh install (2026-12-04: opencv 5.1.0, pin 4.1.0,
    numpy 2.4.6), every start on the far twin and the true wrist reported only as an alternative. Why
    not refitted: at close range a fit is poor (residuals 5 times the noise) and a refit converges on
    its own, further than the winner did (the milling arm on its track: the far twin, refitted, 670
    noise variances lower than the true side), and the lower one then won on convergence alone."""
    from .uncertainty import _wrist_twins

    out = []
    for q in _wrist_twins(robot, lead["q"], lead["free"]):
        pos = robot.positions(q)
        rn = np.linalg.norm(lead["view"].apply(pos)[0] - np.nan_to_num(tracks), axis=-1)
        objective = (_robust(rn, w, lead["delta"]) if lead["prior"] is None else
                     _smoothed_objective(lead["prior"], robot.angles(q), rn, w, lead["delta"]))
        out.append(dict(lead, q=q, pos=pos, rn=rn, objective=objective, sse=float((w * rn ** 2).sum()), twin=True))
    return out


def _trust(robot: RobotKinematics, best: dict, fits: list[dict], tracks: np.ndarray, w: np.ndarray,
           search_ties: bool = False) -> dict:
    """What the perspective fit knows (:func:`chainspace.robot.uncertainty.assess_fit`): per-frame joint
    standard deviations with the static pinhole camera (pose, and the focal when fitted: the view's
    parameters) eliminated, the measured pixel noise, and the other starts' fits that tie with the
    winner as alternatives. Perspective decides the camera side, so no camera-side rule sets one aside."""
    from .uncertainty import assess_fit

    st = best["start"]
    for r in fits:  # (best among them) in the weak fit's layout, which assess_fit reads
        r["out"] = (r["q"], r["view"], r["rn"], r["pos"], r["conv"], r["n_iter"])
    best["free_prior"] = st["free_prior"]
    var = _noise_variance(best, w)
    return assess_fit(robot, best, [(r["objective"], r) for r in fits], var, tracks, w, best["prior"], st["blind"],
                      st["gauge"], lambda r: False, "", search=search_ties)


# a graft fitted on every k-th frame (:func:`_grafted`) is refitted on every frame where it ends there as another
# motion than the winner's, within this many noise variances of the winner fitted alike. Only a graft that beats
# the winner counts. On the Panda (K known, 300 frames) 33 of its 35 grafts came back to the winner's motion on the
# samples (and on every frame, 0.03-0.5 px^2 below it in 3600: not a win); the other two were 1500 and 7800 px^2
# above it there. On the milling arm on its track (K known, 300 frames) the grafts more than a variance above the
# winner on the samples were 0.9-2600 px^2 above it on every frame; four of those that came back to its motion
# there (1.3-2.7 degrees away) went on to fits 6-9 px^2 lower on every frame (0.1-0.2 %, within the tied basin of
# its loose wrist, which is flagged either way). Keeping just the three that beat the winner most on the samples
# (tried at stop 62), the milling arm on its track with lens distortion (150 frames) reported its wrist's other
# tied basin, 84-104 degrees off (flagged, 3D error 2.3 % of reach against 0.12 %)
GRAFT_VARIANCES = 1.0


def _grafted(robot: RobotKinematics, best: dict, others: list[np.ndarray], tracks: np.ndarray,
             w: np.ndarray) -> np.ndarray | None:
    """The winner's joints up to k with another start's joints from k on (every k, every other start),
    refitted from the winner's camera: q (F, nq) of the lowest robust objective if it is below the
    winner's own refitted one, else None.

    Why: each start is fitted under its own camera, and a start whose arm is off (the weak fit's camera
    placed for another branch) ends in a poor minimum even when its wrist is on the right side of the
    depth mirror. Under the winner's camera, the wrist branch that perspective prefers is then found
    by its objective (xArm7, K known, seed 0: 491.5 -> 265.3, the true motion's own minimum; wrist
    joints 120 / 83 / 101 -> 0.8 / 0.9 / 2.2 degrees). Tails are swapped per joint angle
    (:meth:`RobotKinematics.angles`), so a continuous joint's (cos, sin) moves as one. On a long sequence
    only the grafts that end within :data:`GRAFT_VARIANCES` of the winner on every k-th frame, as another
    motion (:func:`_tying`, unsmoothed as the refits), are refitted on every frame (why: beside
    GRAFT_VARIANCES).
    """
    view, free, delta = best["view"], best["free"], best["delta"]
    ones = np.ones(view.n_params, bool)

    def refit(q):
        out = _sequence_lm(robot, q, tracks, w, view, free, ones, 30, 1e-8, delta)
        return out[0], _robust(out[2], w, delta)

    a_best = robot.angles(best["q"])
    grafts = []
    for q in others:
        a = robot.angles(q)
        d = robot.wrap_angles(a - a_best)
        for k in range(1, robot.nv):
            if np.abs(d[:, k:]).max() < 0.05:
                break  # the same tail from here on: nothing new for this or larger k
            a0 = a_best.copy()
            a0[:, k:] = a[:, k:]
            grafts.append(robot.from_angles(a0))
    unsmoothed = dict(best, prior=None, start=dict(best["start"], free_prior=free))  # screened as refitted
    near = _tying(robot, unsmoothed, grafts, tracks, w, GRAFT_VARIANCES, new_only=True)
    grafts = [g for g, t in zip(grafts, near) if t]
    (_, base), *refitted = map_tasks(robot, refit, [best["q"]] + grafts)
    winner = None
    for q1, obj in refitted:
        if obj < base - 1e-3 * abs(base):  # not a rounding-level tie
            base, winner = obj, q1
    return winner


# the winner's path moved along each frame's least-measured direction on windows of this many seconds
# (:func:`_weak_windows`); a window of the per-frame weak std above AMBIGUOUS_DEG is where the motion
# prior, not the tracks, places the path
WEAK_WINDOW_S = 2.0
WEAK_MAX_WINDOWS = 8


def _frame_information(robot: RobotKinematics, lead: dict, tracks: np.ndarray,
                       w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """What each frame's tracks alone say about the joint angles of the fit ``lead`` (q, view, delta, rn,
    start) under its camera: the Gauss-Newton matrix of the frame's robust reprojection errors (F, nv, nv;
    px^2 / rad^2), with the directions that are held or slide (a slide's metres are not on the degrees'
    scale) pinned by a large diagonal; those movable directions (F, nv); and the noise variance (px^2).
    Its inverse times the variance is the frame's covariance without the motion prior."""
    q, view, st = lead["q"], lead["view"], lead["start"]
    var = _noise_variance(lead, w)
    pos, jac = robot.jacobians(q)
    pred, y = view.apply(pos)
    res = pred - np.nan_to_num(tracks)
    ww = w * _huber(np.linalg.norm(res, axis=-1), lead["delta"])[1]
    movable = st["free_prior"] & ~robot.prismatic_v
    H = _normal_equations(view, jac, y, res, ww, movable, np.zeros(view.n_params, bool))[0]
    return H + (~movable)[:, :, None] * np.eye(robot.nv) * 1e12 * (1.0 + np.abs(H).max()), movable, var


def _joint_deviations(H: np.ndarray, var: float) -> np.ndarray:
    """(F, nv) degrees: each joint's standard deviation from one frame's tracks alone, the other joints free
    (the diagonal of ``var`` times the inverse of :func:`_frame_information`'s H (F, nv, nv)); vast where a
    frame's tracks say nothing of a joint (its points hidden there: H is singular, which a plain inverse
    refused with a LinAlgError: a UR10 with an occluder over its wrist for 9 frames)."""
    lam, vec = np.linalg.eigh(H)
    return np.degrees(np.sqrt(var * np.einsum("fvk,fk->fv", vec ** 2, 1.0 / np.maximum(lam, 1e-300))))


def _weak_windows(robot: RobotKinematics, lead: dict, tracks: np.ndarray, w: np.ndarray, fps: float) -> list[dict]:
    """Other minima of the smoothed objective near the winner ``lead`` (a smoothed perspective fit: q,
    view, delta, prior, start), on windows: per frame the direction of the joint angles that the
    frame's tracks fix least (the smallest eigenvalue of the Gauss-Newton matrix of its reprojection
    errors under the winner's camera, its sign carried on from frame to frame) and its standard
    deviation from the tracks alone; on windows of :data:`WEAK_WINDOW_S` seconds (half overlapping)
    where that exceeds the tie policy's AMBIGUOUS_DEG in most frames (:data:`WEAK_MAX_WINDOWS` at most,
    the loosest first), the winner's path moved along it by SHAKE_DEG (as
    :func:`chainspace.robot.uncertainty._shaken` moves a joint; a raised cosine over the window) either
    way, then refitted smoothed with the camera (the winner's prior and objective). Returns fit dicts
    as :meth:`PerspectiveRefinement.finish` makes them. Costs one Jacobian pass and at most
    2 x WEAK_MAX_WINDOWS smoothed refits that start next to the winner.

    Why: where a frame's tracks leave a direction loose, the acceleration prior chooses the path along
    it, and two paths can be minima of the smoothed objective that fit alike; the fit's other
    candidates are whole-sequence mirrors, twins and branches, which do not differ on a window only.
    The xArm7 at close range (K known, 300 frames, seed 0): the wrist's joints 5 and 6 traded along a
    direction the tracks fix to 4-10 degrees per frame; the reported path was 4-12 degrees off on
    joint6 over frames 0-42 (3.48 degrees RMS, reported observable) and the path moved there refits to
    a minimum 0.01 noise variances from it, joint6 1.14 degrees RMS off: a tie that nothing reported."""
    from .uncertainty import AMBIGUOUS_DEG, SHAKE_DEG

    q = lead["q"]
    if lead["prior"] is None:
        return []
    F = len(q)
    H, movable, var = _frame_information(robot, lead, tracks, w)
    lam, vec = np.linalg.eigh(H)
    sd = np.sqrt(var / np.maximum(lam[:, 0], 1e-300))  # rad, along the unit direction vec[:, :, 0]
    d = vec[:, :, 0] * movable
    for f in range(1, F):  # one orientation along the sequence
        if d[f] @ d[f - 1] < 0:
            d[f] = -d[f]
    loose = sd > np.radians(AMBIGUOUS_DEG)
    if not loose.any():
        return []
    size = max(int(round(WEAK_WINDOW_S * fps)), 5)
    windows = [(a, min(a + size, F)) for a in range(0, max(F - size // 2, 1), size // 2)]
    windows = [(a, b) for a, b in windows if loose[a:b].mean() > 0.5]
    windows = sorted(windows, key=lambda ab: -np.median(sd[ab[0]:ab[1]]))  # the loosest first
    moved = []
    for a, b in windows[:WEAK_MAX_WINDOWS]:
        taper = np.zeros(F)
        taper[a:b] = np.sin(np.pi * (np.arange(a, b) - a + 0.5) / (b - a)) ** 2
        for sign in (1.0, -1.0):
            moved.append(((a, b), robot.integrate(q, sign * np.radians(SHAKE_DEG) * taper[:, None] * d, clip=True)))
    return map_tasks(robot, lambda m: _smoothed_refit(robot, lead, m[1], tracks, w, 100, 1e-10, window=m[0]), moved)


# the winner's path moved towards each end of the sequence (:func:`_end_moves`): how many of those moves, after a
# brief refit, are refitted in full (the distinct ones of lowest objective)
END_REFITS = 2


def _end_moves(robot: RobotKinematics, lead: dict, tracks: np.ndarray, w: np.ndarray, fps: float) -> list[dict]:
    """Other minima of the smoothed objective that leave the winner ``lead``'s path towards an end of the
    sequence: each revolute joint that the fit moves, its path shifted by SHAKE_FAR_DEG either way over the
    first or last window (:data:`WEAK_WINDOW_S` seconds, at most half the sequence), ramped from nothing at the
    window's inner edge to the full shift at the sequence's first or last frame (the directions the fit holds
    left as they are), each refitted smoothed with the camera briefly (20
    iterations; on a long sequence only those that tie with the winner on every k-th frame, :func:`_tying`);
    the :data:`END_REFITS` distinct ones of lowest objective then refitted in full. Returns fit
    dicts as :meth:`PerspectiveRefinement.finish` makes them, each with ``window`` (the frames moved).

    Why: the acceleration prior holds a path's ends from one side only, so a path can part from the true one
    towards an end, where another branch of the robot's kinematics fits the tracks too; the whole-path shakes
    (:func:`chainspace.robot.uncertainty._shaken`) move every frame alike and the windows
    (:func:`_weak_windows`) only where the tracks leave a direction loose. The Solo12 from below (full ranges,
    pinhole, 30 frames, seed 79): the front left hip and knee parted from the truth over the last 12 frames,
    by up to 39 degrees (15 RMS, reported observable) in a minimum 69 noise variances above the true motion's;
    the winner's hip path ramped by -60 degrees over the last half refits to the true motion's minimum."""
    from .uncertainty import SHAKE_FAR_DEG

    q = lead["q"]
    F = len(q)
    if lead["prior"] is None or F < 6:
        return []
    size = min(max(int(round(WEAK_WINDOW_S * fps)), 5), F // 2)
    free = lead["start"]["free_prior"]
    moved_joints = np.flatnonzero(free.any(0) & ~robot.prismatic_v)
    ramp = np.arange(1, size + 1) / size
    moves = []
    for a, b, taper in ((0, size, ramp[::-1]), (F - size, F, ramp)):
        for k in moved_joints:
            for sign in (1.0, -1.0):
                dv = np.zeros((F, robot.nv))
                dv[a:b, k] = sign * np.radians(SHAKE_FAR_DEG) * taper
                # (a held direction stays: the first joint seen relative to frame 0 is held at rest there)
                moves.append(((a, b), robot.integrate(q, dv * free, clip=True)))
    tying = _tying(robot, lead, [m[1] for m in moves], tracks, w)
    brief = map_tasks(robot, lambda m: _smoothed_refit(robot, lead, m[1], tracks, w, 20, 1e-6, window=m[0]),
                      [m for m, t in zip(moves, tying) if t])
    return map_tasks(robot, lambda r: _smoothed_refit(robot, lead, r["q"], tracks, w, 100, 1e-10, window=r["window"]),
                     _lowest_distinct(robot, brief, q, END_REFITS))


def _tying(robot: RobotKinematics, lead: dict, paths: list[np.ndarray], tracks: np.ndarray,
           w: np.ndarray, variances: float | None = None, new_only: bool = False) -> list[bool]:
    """Per path (F, nq) that a search moved the winner ``lead`` to, whether it may tie with lead: on a
    sequence longer than ``uncertainty.SHAKE_FRAMES``, fitted briefly on every k-th frame it ends within the
    tie tolerance of lead fitted alike (:func:`chainspace.robot.uncertainty._tied_on_samples`); on a short
    one, every path. A path that does not tie is neither a tie nor a better winner, and its refits on every
    frame were most of a long fit's search: the Panda (K known, 300 frames, one thread), the loosest
    joints' 63 turned paths 5.8 s of a 19 s fit. ``variances``: the tolerance in noise variances (default the
    tie tolerance); ``new_only``: a path that ends there as lead's own motion does not tie."""
    from .uncertainty import _sample_step, _tied_on_samples

    step = _sample_step(len(lead["q"]))
    if step == 1 or not paths:
        return [True] * len(paths)
    return _tied_on_samples(robot, dict(lead, out=(lead["q"], lead["view"])), paths, tracks, w, lead["prior"],
                            lead["start"]["free_prior"], _noise_variance(lead, w), step, variances, new_only)


def _lowest_distinct(robot: RobotKinematics, fits: list[dict], q: np.ndarray, n: int) -> list[dict]:
    """The ``n`` fits of lowest objective that are other motions than q (F, nq) and than each other
    (:func:`chainspace.robot.candidates._same_motion`): the brief refits worth refitting in full."""
    kept: list[dict] = []
    for r in sorted(fits, key=lambda r: r["objective"]):
        if len(kept) == n:
            break
        if not _same_motion(robot, r["q"], q) and not any(_same_motion(robot, r["q"], k["q"]) for k in kept):
            kept.append(r)
    return kept


def _smoothed_refit(robot: RobotKinematics, lead: dict, q0: np.ndarray, tracks: np.ndarray, w: np.ndarray,
                    max_iter: int, tol: float, **tag) -> dict:
    """q0 (F, nq) refitted smoothed, camera too, under the winner ``lead``'s camera, motion prior, Huber
    threshold and free directions: a fit dict as :meth:`PerspectiveRefinement.finish` makes them, with
    ``tag`` (``window=``, ``turn=``: what the other-minima searches mark their fits with)."""
    view, delta, prior, st = lead["view"], lead["delta"], lead["prior"], lead["start"]
    o = _smooth_lm(robot, robot.continuous(q0), tracks, w, view, st["free_prior"], np.ones(view.n_params, bool),
                   max_iter, tol, delta, prior)
    return dict(q=o[0], view=o[1], rn=o[2], pos=o[3], conv=o[4], n_iter=lead["n_iter"] + o[5],
                objective=_smoothed_objective(prior, robot.angles(o[0]), o[2], w, delta),
                sse=float((w * o[2] ** 2).sum()), free=lead["free"], delta=delta, prior=prior, start=st, **tag)


# the loosest joints' paths turned whole by multiples of this (:func:`_loose_turns`), and how many are turned
TURN_STEP_DEG = 45.0
TURN_MAX_JOINTS = 2
TURN_REFITS = 4  # the distinct turned fits of lowest objective refitted in full


def _loose_turns(robot: RobotKinematics, lead: dict, tracks: np.ndarray, w: np.ndarray) -> list[dict]:
    """Other minima of the smoothed objective along the joints the tracks fix least: the
    :data:`TURN_MAX_JOINTS` revolute joints whose standard deviation from each frame's tracks alone
    (:func:`_frame_information`) is above the tie policy's AMBIGUOUS_DEG in most frames, the loosest
    first; the winner ``lead``'s whole path turned on those joints by every combination of multiples of
    :data:`TURN_STEP_DEG` (all but none), each refitted smoothed with the camera under the winner's
    prior, briefly (20 iterations); the :data:`TURN_REFITS` distinct ones of lowest objective then
    refitted in full; on a long sequence only the turned paths that tie with the winner on every k-th frame
    (:func:`_tying`). Returns fit dicts as :meth:`PerspectiveRefinement.finish` makes them, each with ``turn``
    (the joints' names and the turns in degrees).

    Why: where the tracks fix a wrist's joints to a few degrees per frame, the smoothed objective can have
    minima tens of degrees apart along them, and which one the starts reach is chance: the milling arm on its
    track (lens distortion, intrinsics known, 300 frames, seed 0) ended 85-101 degrees off on joints a4 and a6
    (3D error 2.2 % of reach) in a minimum 44 noise variances above the true motion's, which no start reached
    (the same row without distortion did: other noise). There its two loosest joints are a6 and a5 (3-8 degrees
    per frame); turned by multiples of 45 degrees, four of the 63 starts reach the true minimum's wrist twin,
    and the tie policy then keeps the true one. The windows (:func:`_weak_windows`) move the path by SHAKE_DEG,
    within the same basin, and the twins are discrete symmetries. Cost: 10-13 s on that row (300 frames, an
    idle machine) before the turns were first fitted on samples; the Panda (K known, 300 frames, one thread):
    5.8 s of a 19 s fit, 0.7 s since; none where no joint is loose."""
    from .uncertainty import AMBIGUOUS_DEG

    q = lead["q"]
    if lead["prior"] is None:
        return []
    H, movable, var = _frame_information(robot, lead, tracks, w)
    sd = _joint_deviations(H, var)
    loose = np.flatnonzero(movable.all(0) & robot.turns_v & (np.median(sd, 0) > AMBIGUOUS_DEG))
    loose = loose[np.argsort(-np.median(sd[:, loose], 0))][:TURN_MAX_JOINTS]
    if not len(loose):
        return []
    steps = np.radians(TURN_STEP_DEG) * np.arange(1, int(round(360.0 / TURN_STEP_DEG)))
    grids = np.stack(np.meshgrid(*[np.r_[0.0, steps]] * len(loose), indexing="ij"), -1).reshape(-1, len(loose))[1:]

    names = [robot.joint_names[v] for v in loose]

    def turned(turn):
        dv = np.zeros((len(q), robot.nv))
        dv[:, loose] = turn
        return robot.integrate(q, dv, clip=True)

    paths = [turned(turn) for turn in grids]
    tying = _tying(robot, lead, paths, tracks, w)
    brief = map_tasks(robot, lambda k: _smoothed_refit(robot, lead, paths[k], tracks, w, 20, 1e-6, turn=dict(
        zip(names, np.degrees(grids[k]).round(1).tolist()))), [k for k in range(len(paths)) if tying[k]])
    return map_tasks(robot, lambda r: _smoothed_refit(robot, lead, r["q"], tracks, w, 100, 1e-10, turn=r["turn"]),
                     _lowest_distinct(robot, brief, q, TURN_REFITS))
