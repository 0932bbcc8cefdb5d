"""Joint angles of a robot from its reconstructed 3D motion, refined straight on its 2D tracks.

A chain made by :func:`chainspace.from_urdf` has one point per URDF link origin (plus tool frames);
Pinocchio knows each of them as a frame. :func:`fit_joint_angles` finds, for every frame of a
sequence, the joint angles ``q`` that put those frames where the points were seen:

1. **3D fit.** A monocular reconstruction is known only up to a similarity (scale, rotation,
   translation) and, under weak perspective, a depth mirror. One similarity ``X = s R x(q) + t`` for
   the whole sequence is estimated with the joint angles: a start found by trying rotations spread
   over SO(3) on a few frames; IK along the sequence warm-started from the previous frames; then
   Umeyama's closed form alternated with per-frame damped Gauss-Newton (Levenberg-Marquardt) on
   Pinocchio frame Jacobians; then all together. Joint limits are kept by projection. Both the poses
   and their mirror image are fitted.
2. **Model-based refinement** (default when 2D tracks are given): with the link lengths known from
   the URDF, the joint angles and a weak-perspective camera ``u = s R[:2] x(q) + t2`` are fitted
   straight to the tracks (reprojection error in pixels, confidence weights, a robust Huber loss,
   NaN = not seen). By default one static camera for the whole sequence (a tripod in front of a robot
   on a fixed base); ``camera="per-frame"`` gives each frame its own. The normal equations have one
   block per frame plus the shared camera, which a Schur complement eliminates, so an iteration costs
   one Jacobian pass over the frames (all frames batched) and small batched solves. A prior on joint
   accelerations (``accel_std``) then averages the pixel noise over neighbouring frames; its banded
   system is solved by a banded Cholesky factorisation. Where no tracked point a joint moves is seen,
   the prior alone carries the joint: between two sightings it bridges them smoothly, but before the
   first or after the last one it would carry the joint on at its last speed for ever (a straight
   ramp costs no acceleration). ``speed_decay_s`` also charges the joint's speed there, so that it
   decays with that time constant and the joint comes to rest. Off by default: over a second unseen
   neither guess wins on the benchmarks (docs/benchmarks.md, robustness section; ``benchmarks/bench_hidden_ends.py``),
   but over longer stretches at the ends a constant speed runs on to the joint limits.

Ambiguities the tracks cannot settle, and the rules that settle them
--------------------------------------------------------------------
Under weak perspective several motions can put every tracked point on its track exactly. The fit
generates them as candidates and, among those that fit alike (squared residuals within 25 noise
variances of the best: a likelihood-ratio test), applies these rules:

* *Mirror image.* A motion and its depth mirror project alike; for a robot built mirror-symmetric
  (its tracked points in one vertical plane at rest, as on most industrial arms) the mirror is a
  valid motion of the same robot, seen from the other side of its base plane. ``view_from="above"``
  (default) keeps the one whose camera looks down on the base plane (or level). The mirror about the
  robot's own symmetry plane, seen through a mirrored camera, is tried too. For a robot only nearly
  symmetric (a tool marker off the plane), the wrong mirror image can fit the tracks slightly better
  frame by frame, by moving less plausibly: with the acceleration prior on (the default) the
  candidates are compared by the smoothed objective (robust residuals plus the prior), the mirror
  image of the winner is smoothed and scored too, and the camera side decides only among those that
  tie there; of those seen from that side, the motion that moves least is kept.
* *Where the camera stands round the base.* With a static camera, a turn of the first joint looks
  like a turn of the camera (the joint is reported relative to frame 0), so how far round the base
  the camera stands is part of the start, and the smoothed search stays near the side it starts
  from. With the upper arm hidden for most of a sequence, every start can meet a motion seen from
  below with the first joint wandering; so the winner is also smoothed from views turned a quarter,
  a half and three quarters about that joint's axis, and scored with the rest.
* *Planar bodies on ball-like joints.* Where every tracked point beyond a joint group lies in one
  plane with its centre (a spherical wrist carrying a planar tool; a 7-axis arm's spherical
  shoulder), that part mirrored in depth about the centre is again a pose of the robot, in every
  frame. Per frame the fit tries each link's depth flip, then chooses the path through all frames
  by dynamic programming: a jump to another branch between frames costs, and of two continuous
  paths that fit alike, the one nearer the rest pose is kept (joints within about 70 degrees of
  their rest values come out right). Where the camera sees that plane nearly face-on the two
  branches meet, its tilt in depth is seen only to second order, and a noisy path can leave on the
  other branch (the shipped milling arm's tool roll, on some views). Nothing in the tracks or in
  the smoothness of the motion tells the two apart there (the mirrored path is as smooth), so
  ``fit.message`` names the plane, its joints and the frames within 15 degrees of face-on. Track a
  point off the plane (``extra_frames={"tool_marker": ("spindle", [0, 0.08, 0])}``): the tilt is
  then seen to first order.
* *Ball-like shoulder with every base point on the first axis* (Panda, xArm7 and similar 7-axis
  arms): the whole arm beyond the shoulder mirrors exactly, in every frame, and the rest-pose rule
  picks wrongly as often as not. Track a point on the first link's housing, off its axis
  (``extra_frames={"shoulder_marker": ("panda_link1", [0.08, 0, -0.1])}``); the benchmark does.
* *Mirror images far in joint space.* The mirror image of the whole motion (seen through the
  mirrored camera), or of the arm beyond a ball-like shoulder, can be a pose of the robot whose joints
  differ from the fitted ones by up to half a turn (a UR10, its links offset sideways; the Panda
  beyond its shoulder), which IK started from the fit does not reach. Where the 3D fit of a reflected
  motion misses its points, and for every link's depth flip when the fit is assessed, that pose is
  searched for on a few frames from random configurations and joined into one continuous path
  (``candidates._far_poses``); the flips found are smoothed and scored as the winner was. Where the
  whole mirror is no pose of the robot, so is the mirror of the arm up to each link (the links beyond
  it mirrored back: the same image), searched alike and refined from the whole path (a Kinova arm).
* *Seen again after a long gap.* A joint unseen for long enough to turn half a circle at the branch
  search's step bound (``_LONG_GAP`` frames), then seen again, may come back on any branch, and the
  frame that sees it again may fit a wrong one as well as the true one (a wrist seen in one frame
  after its tool was hidden for more than a second). The acceleration prior charges nothing for a
  straight ramp across the gap, so every branch of that frame, bridged to the last sighting by a
  straight line and smoothed, can score alike: of those that tie, the motion that moves least
  (the sum of squared joint steps) is kept.
* *The tie policy.* All the rules above use one candidate type (a fitted motion, ``q`` with the
  solver's output), one tolerance (objectives within ``candidates.TIE_VARIANCES`` = 25 noise
  variances), one de-duplication (motions within ``candidates.DISTINCT_RAD`` = 0.05 rad in every
  frame and joint are one; a joint seen only relative to frame 0 compared as its change since frame 0
  where the alternatives are listed) and one distance to rest (``kinematics._rest_distance``). The camera-side
  rule decides only where it is valid (``selection.view_side_valid``: the robot stands above its base
  plane; legs or a hanging limb do not). What the rules could not settle validly is reported, not
  hidden: ``fit.alternatives`` (the tied motions, the reported motion's exact depth-flip twins
  included) and ``fit.ambiguous`` (joints where one differs by more than
  ``uncertainty.AMBIGUOUS_DEG`` = 2 degrees RMS, or two of its standard deviations do); ``fit.q_std``
  gives per-frame standard deviations from the fit's Gauss-Newton covariance
  (:mod:`chainspace.robot.uncertainty`).
* *Singularities.* Where two joint axes align (a wrist stretched straight; a 7-axis arm's upper arm
  along its first axis) only the sum of their angles is seen, and a path may continue on either
  branch. Nothing in the tracks can split them there; plan paths (and camera checks) away from them,
  as :func:`chainspace.synthesize` does.

Perspective (a pinhole camera)
------------------------------
With ``intrinsics`` (a camera with ``K`` and ``undistort``, or a 3x3 K) the tracks are undistorted and
the weak-perspective fit above runs on them, without its smoothed choice among candidates, and on at most
``START_FRAMES`` (100) of them evenly spread, its starts then interpolated in time to every frame (they
only start the fit below, which chooses every frame's branch again: the weak fit was 44 % of a 300-frame
perspective fit's time, docs/benchmarks.md, Robot fit speed, stop 56). With the focal length unknown the
same, except that on at most 100 frames the weak fit is the full one (smoothed, assessed), and on more
it is made again in full on every frame where it is to be reported (no measurable perspective, below).
Where the fit from those starts ends poor or not converged on a joint (the assessment's flags), it is
made again from a weak fit of every frame: on fast motions the sparse frames' branch search can miss the
motion's basin (the Kinova from below, full ranges, 150 frames, pinhole seed 66: 45-111 degrees off,
flagged poor; 0.2-0.8 from every frame). Then one static pinhole camera
``u = f (R x + t)_xy / (R x + t)_z + c`` (rotation, translation in metres: the URDF fixes the scale)
and the joint angles of every frame are fitted on the perspective reprojection
error in pixels, with the same robust loss, confidences and acceleration prior (the view
:class:`~chainspace.robot.views._PinholeView`; the solvers are the weak fit's). Its start: the weak
camera's rotation, the depth of the robot's centroid ``f / s`` from the weak scale s (and, with K
known, the camera OpenCV's PnP finds for the start's points: a small robot near the camera makes the
weak motion, and so the weak camera, far off), then the camera alone and per-frame IK under it,
alternated (of the two camera starts, the better fit is kept), all together, and the branch of every
frame chosen again under the pinhole camera (the Viterbi pass above). A fit with points behind its
camera (which a pinhole projects as it projects their mirror through the camera centre) is dropped.

Perspective settles the depth mirror: a motion and its mirror image no longer project alike, so
the perspective fit starts from the weak fit's winner *and* its distinct alternatives (mirror images,
the reflection about the symmetry plane): each through the camera stage, the winner and the two
others that fit best there refined in full (``perspective.MAX_STARTS``), and the lowest perspective
objective wins. Where the best of them leaves squared residuals above twice what the tracks' own
jitter allows (a robot close to a wide lens, whose weak starts are tens of degrees off), or beats weak
perspective's by more than 25 jitter variances (perspective measurable: the weak starts may all lie in
another motion's basin), one more start competes: the camera searched in full perspective on a few
frames and every frame's joints by IK under it (:mod:`chainspace.robot.pinhole_start`; not where the
camera it finds is the winner's own).
The camera-side rule (``view_from``) and the rest-pose rule then decide nothing; ``message`` says
whether the choice was clear (the objectives more than 25 noise variances apart) or a guess. The
joints seen only relative to frame 0, and the face-on planes of a wrist, are as above (a turn about
the base axis is still a turn of the camera; a plane seen face-on is still tilted only to second
order), except that a joint is held in frame 0 only where a change of view imitates it at every
configuration (every tracked base point on its axis): one the weak fit held because of its
configuration alone (the double pendulum's first joint, its base point off the axis) is fitted in
every frame and reported observable.

With ``image_size`` and no intrinsics the focal length is fitted too (``log f`` a seventh camera
parameter; principal point at the image centre; starts at 0.5, 1, 2 and 4 image widths, the camera
alone fitted from each). Its standard deviation comes from the Gauss-Newton covariance of the camera
with the joint angles eliminated (Schur complement, without the motion prior: an upper bound), scaled
by the residual variance. Where the focal's standard deviation exceeds 25 % of it, or perspective
does not beat weak perspective's squared residuals by 25 noise variances (a likelihood-ratio test),
the tracks carry no measurable perspective (a far camera, a long lens): the weak-perspective fit is
reported, ``message`` says so, and ``focal_px``/``focal_std_px`` hold what was estimated.

With ``perspective=True`` and neither intrinsics nor image size, the principal point is fitted as
well (two more camera parameters, started at the centre of the tracks' extent; the focal starts are
those of an image twice as wide as that extent): the fit then does not depend on where in the image
the robot stands (shifting every track shifts the principal point alike). Through ``synthesize``'s
phone and industrial cameras (60 frames, 1 px; ``benchmarks/bench_no_camera.py --image-size
unknown``) the joints came out as a fit given the image size does, where a principal point guessed
470 px off (a robot filmed off-centre) left joints 2-8 degrees off unflagged.

The perspective fit says how sure it is as the weak one does (``q_std``, ``noise_px``,
``alternatives``, ``ambiguous``: :func:`chainspace.robot.uncertainty.assess_fit`), with the static
pinhole camera (rotation, translation and, when estimated, log f) eliminated from the covariance by
the Schur complement; the other starts' perspective fits are the candidates for alternatives, and the
weak fit's ambiguity notes, which perspective re-decides, are dropped.

Observability (the rule)
------------------------
A joint is observable when moving it moves some tracked point in a way no change of camera (or, in
3D, of the similarity) can imitate. Two cases are detected from the stacked Jacobians of the tracked
points and reported in ``fit.observable`` / ``fit.relative`` and ``fit.message``:

* *No tracked point moves with the joint* (a last joint whose axis runs through the only tracked
  point of its link; fingers of a gripper that is not tracked). The joint is held at its rest value
  and marked unobservable.
* *Its motion equals a motion of the camera*: the first joint turning about the base's vertical axis
  when every tracked point of the base lies on that axis (everything it turns, turns with it, which a
  turn of the camera imitates). A static camera sees it only relative to the
  first frame: it is held at its rest value in frame 0 and fitted in every other frame
  (``fit.relative[k]`` is True, ``fit.observable[k]`` False). With ``camera="per-frame"`` each
  frame's camera absorbs it and it is held at its 3D-fit value.

To make such a joint observable: for the first kind, track a point that moves with the joint, off its
axis (a tool tip off the flange axis); for the second, a point fixed to the link the joint turns
against, off the axis (a mark on the base plate). Give them to ``from_urdf`` as
``extra_frames={"base_mark": ("base_link", [0.3, 0, 0]), "tool_tip": ("tool0", [0, 0.05, 0.2])}``.

Conventions: ``fit.q`` is (F, nq) in the order of the Pinocchio model built from the same URDF
(``pinocchio.buildModelFromUrdf(path, mimic=True)``, :func:`chainspace.io.urdf.build_model`): a
continuous joint holds (cos, sin) there. ``fit.angles`` (F, nv) has one coordinate per joint, in the
order of ``fit.joint_names`` (as ``fit.observable`` and ``fit.relative``): radians for revolute and
continuous joints, metres for prismatic ones; a mimic joint is driven by its leader and is no joint of
its own there. Floating bases (and other multi-dof joints) are refused with a DescriptionError. Lengths
in metres, image coordinates in the units of the tracks (pixels). Cameras map points of the robot's
base frame to the image.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any
import numpy as np

from ..chain import KinematicChain
from ..errors import ConvergenceWarning, DescriptionError, TrackError, is_real
from ..progress import stage
from .kinematics import RobotKinematics
from .result import JointFit
from .views import _align, similarity_align
from .solver import _rms_per_frame, _sequence_lm
from .starts import _fit_3d
from .observability import _fill_unseen, _gauge_directions, _hold, _hold_with_prior, _notes, _structural, _unseen, \
    _weights
from .candidates import FACE_ON_DEG, _face_on_planes, _frame_ranges, _same_motion
from .selection import _prefer_rest
from .uncertainty import CAMERA_MISFIT_RATIO, camera_misfit, track_jitter
from .weak_refine import WeakRefinement

__all__ = ["JointFit", "RobotKinematics", "fit_joint_angles", "similarity_align"]


# the most frames that the weak fit starting a perspective fit looks at: it only gives starts, whose branches
# the perspective fit chooses again in every frame (_start_stride). Not fewer: at 60 (tried at stop 62) the
# milling arm on its track, focal unknown, 150 frames (bench_pinhole_robots.py --frames 150) ended with no
# perspective measured and the weak fit reported, joint_a1 8.3 degrees off and reported observable (0.4 at 100)
START_FRAMES = 100
# a fit whose motion conflicts with its motion prior (solver.prior_conflict above this) is made again under
# wider priors, at most this many times (_prior_matched). A fit pulled by a prior that suits the motion moves
# slower than the prior's deviation (0.24-0.27 of it in a probe's controls); a 10 fps clip fitted at the
# default 30 fps (the prior nine times too stiff) showed 1.27-2.02, and was 2.1-2.3 degrees off on a joint
# reported observable at 3 (the full-range sets: widened in 21 of 128 runs, no verdict worse, 8 joints more
# right, docs/benchmarks.md, stop 61)
PRIOR_CONFLICT = 1.2
MAX_WIDENINGS = 2
FACE_ON_NOTE = "the tracked points beyond "
PERSPECTIVE_HINT = ("a camera within a few robot reaches sees the robot in perspective, which this fit (given no "
                    "intrinsics or image size) does not model: pass intrinsics= (a calibration), "
                    "image_size=(width, height) or perspective=True (focal length and principal point "
                    "fitted) to fit under perspective")


def _positive(x: Any) -> bool:
    return is_real(x) and x > 0


def _inputs(rec_or_poses, urdf, chain, tracks, confidence):
    """Unpack and check what the caller gave: (poses, chain, urdf path, tracks, confidence)."""
    if hasattr(rec_or_poses, "poses"):
        rec = rec_or_poses
        poses = np.asarray(rec.poses, float)
        chain = chain or getattr(rec, "chain", None)
        if tracks is None:
            tracks = getattr(rec, "tracks", None)
            if confidence is None:
                confidence = getattr(rec, "confidence", None)
    else:
        try:
            poses = np.asarray(rec_or_poses, float)
        except (TypeError, ValueError):
            raise TrackError(f"fit_joint_angles needs a Reconstruction or poses (F, J, 3), got "
                             f"{type(rec_or_poses).__name__}") from None
    if urdf is None and chain is not None:
        urdf = chain.metadata.get("urdf_path")
    if urdf is None:
        raise DescriptionError("fit_joint_angles needs the robot's URDF: pass urdf=PATH or a chain made by "
                               "chainspace.from_urdf")
    if chain is None:
        from ..io.urdf import from_urdf

        chain = from_urdf(urdf)
    J = chain.n_joints
    if poses.ndim == 2 and poses.shape == (J, 3):
        poses = poses[None]
    if poses.ndim != 3 or poses.shape[1:] != (J, 3):
        raise TrackError(f"poses have shape {poses.shape}, expected (frames, {J}, 3) for {chain.name} "
                         f"({', '.join(chain.joints[:4])}...)")
    if len(poses) == 0:
        raise TrackError("poses are empty: no frames to fit")
    if np.isinf(poses).any():
        f, j = np.argwhere(np.isinf(poses).any(-1))[0]
        raise TrackError(f"poses contain inf at frame {f}, joint {chain.joints[j]!r}")
    if tracks is not None:
        tracks = np.asarray(tracks, float)
        if tracks.shape != (len(poses), J, 2):
            raise TrackError(f"tracks have shape {tracks.shape}, expected ({len(poses)}, {J}, 2) to match the "
                             f"poses of {chain.name}")
        if np.isinf(tracks).any():
            f, j = np.argwhere(np.isinf(tracks).any(-1))[0]
            raise TrackError(f"tracks contain inf at frame {f}, joint {chain.joints[j]!r}")
    if confidence is not None:
        confidence = np.asarray(confidence, float)
        if confidence.shape != (len(poses), J):
            raise TrackError(f"confidence has shape {confidence.shape}, expected ({len(poses)}, {J})")
        if not np.isfinite(confidence).all() or (confidence < 0).any() or (confidence > 1).any():
            raise TrackError("confidence must hold finite weights in [0, 1]")
    return poses, chain, str(urdf), tracks, confidence


def _mirror_candidates(robot: RobotKinematics, Xz: np.ndarray, w3: np.ndarray, signs: tuple, blind: np.ndarray,
                       gauge0: np.ndarray, free_blind: np.ndarray, free_sim: np.ndarray, unseen3: np.ndarray,
                       transform: str, max_iter: int, max_iter_final: int, tol: float) -> tuple[list[dict], int]:
    """Step 1, the 3D fit: the points ``Xz`` (F, J, 3; weights ``w3``) and, for each further sign in
    ``signs``, their mirror image, each fitted with the joint angles and one transform (a similarity, a
    rigid motion or none), the directions a turn of that transform imitates (``gauge``) held; the
    candidates ordered by :func:`~chainspace.robot.selection._prefer_rest`, and the solver's iterations."""
    candidates, n_iter = [], 0
    for sign in signs:
        X = sign * Xz
        q, view, n_iter_a = _fit_3d(robot, X, w3, free_blind, transform, max_iter, tol,
                                    gauge0 if transform != "none" else blind & False)
        gauge, free = np.zeros(robot.nv, bool), free_blind
        if transform != "none":
            pos, jac = robot.jacobians(q)
            gauge = _gauge_directions(pos, jac, w3, None, False) & ~blind
            q, free = _hold(robot, q, blind, gauge, False, unseen3)
            view = _align(robot.positions(q), X, w3, transform)  # the hold turned the robot: turn the view back
        q, view, rn, pos, conv, it = _sequence_lm(robot, q, X, w3, view, free, free_sim, max_iter_final, tol, None)
        n_iter += it + n_iter_a
        candidates.append(dict(sign=sign, q=q, view=view, rms=float(np.sqrt((w3 * rn ** 2).sum() / w3.sum())),
                               conv=conv, gauge=gauge, pos=pos))
    return _prefer_rest(robot, candidates, "rms", blind), n_iter


def fit_joint_angles(
    rec_or_poses: Any,
    urdf: str | Path | None = None,
    *,
    chain: KinematicChain | None = None,
    tracks: Any = None,
    confidence: Any = None,
    camera: str = "static",
    refine: bool = True,
    transform: str = "similarity",
    max_iter: int = 100,
    tol: float = 1e-6,
    loss_scale_px: float | None = None,
    mirror: bool = True,
    view_from: str | None = "above",
    fps: float = 30.0,
    accel_std: float | None = 3.0,
    jerk_std: float | None = 10.0,
    speed_decay_s: float | None = None,
    intrinsics: Any = None,
    image_size: tuple[float, float] | None = None,
    perspective: bool | None = None,
    search_ties: bool = True,
    _starts: list | None = None,
    _assess: bool = True,
) -> JointFit:
    """Fit the robot's joint angles to a reconstruction (and its 2D tracks).

    Parameters
    ----------
    rec_or_poses
        A :class:`chainspace.Reconstruction` of a chain made by ``from_urdf`` (its tracks and
        confidences are used), or 3D points (F, J, 3) in the chain's order (NaN = missing).
    urdf
        Path of the URDF; default ``chain.metadata["urdf_path"]``.
    chain
        The chain of the points; default the reconstruction's, else ``from_urdf(urdf)``.
    tracks, confidence
        2D tracks (F, J, 2) in pixels (NaN = not seen) and weights (F, J) in [0, 1]. With tracks and
        ``refine=True`` the joint angles and the camera are refined on the reprojection error.
    camera
        ``"static"`` (one camera for all frames, the default for a robot filmed from a tripod) or
        ``"per-frame"``.
    transform
        How the 3D points relate to the robot's base frame: ``"similarity"`` (a monocular
        reconstruction: unknown scale, rotation, translation and mirror), ``"rigid"`` (metric points in
        another frame) or ``"none"`` (points already in the base frame, metres: every joint that moves
        a tracked point is then observable, the first one included).
    max_iter, tol
        Iteration cap of each Levenberg-Marquardt run and the relative cost decrease that stops it.
    loss_scale_px
        Huber threshold of the 2D loss in pixels; None: 3 robust standard deviations of the residuals
        of the 3D fit's start; 0: plain least squares.
    mirror
        Also try the depth-mirrored poses (weak perspective cannot tell them apart) and keep the better.
    fps, accel_std
        Frame rate (1/s) and the prior on joint accelerations (rad/s^2, RMS): the 2D refinement adds
        ``sum |q[f-1] - 2 q[f] + q[f+1]|^2`` weighted so that accelerations of ``accel_std`` cost as
        much as pixel noise of the size of the residuals. Robots move smoothly; the prior averages the
        noise over neighbouring frames (the wrist joints, seen through short links, gain most). None:
        every frame on its own. Where the fitted motion is faster than the priors allow (a joint's RMS
        acceleration or jerk above :data:`PRIOR_CONFLICT` times ``accel_std`` / ``jerk_std``: a fast robot,
        or too low an ``fps``), the fit is made again under priors widened to the motion's pace, and says so;
        ``fit.accel_std``, ``fit.jerk_std`` are the priors used.
    jerk_std
        The prior on joint jerks (rad/s^3, RMS) that the answer is finished under: the fit searches for
        the motion, and for the others that fit as well, under the acceleration prior, then finishes each
        of them under ``sum |q[f+2] - 3 q[f+1] + 3 q[f] - q[f-1]|^2``, weighted alike, which lets a joint
        keep its acceleration where the tracks say little (near a singularity, at the ends of a sequence)
        instead of pulling it towards rest; the standard deviations and ties are taken under it. None: the
        answer stays under the acceleration prior. Used with ``accel_std``.
    speed_decay_s
        Before the first and after the last frame in which a point it moves is seen, a joint's speed
        decays with this time constant (s), so that the joint comes to rest; None (default): it
        carries on at its last speed, as the acceleration prior alone has it. Used with ``accel_std``.
    view_from
        ``"above"`` (default: the camera looks down on the robot's base plane, or level), ``"below"`` or
        None. Under weak perspective a motion and its mirror image project alike; for a robot built
        mirror-symmetric (most industrial arms) both are valid motions and fit equally well. The camera
        side then decides (image y axis pointing down, as pixel rows do); None: the motion nearer the
        rest pose.
    intrinsics
        The camera that filmed the tracks: an object with ``K`` (3, 3) and ``undistort(pixels)`` (such as
        :class:`chainspace.cameras.PinholeCamera`), a 3x3 matrix K or a calibration file. The tracks are undistorted and
        the joint angles and one static camera pose (rotation, translation in metres) are fitted on the
        perspective reprojection error (see "Perspective" in the module docstring).
    image_size
        (width, height) px of the images, without ``intrinsics``: the focal length is estimated too
        (principal point at the image centre) and reported with its standard deviation; where the tracks
        carry no measurable perspective the weak-perspective fit is kept and ``message`` says so.
        Neither given: weak perspective only, unless ``perspective=True``.
    perspective
        None (default): a pinhole camera where ``intrinsics`` or ``image_size`` is given, else weak
        perspective. True: a pinhole camera in any case; with neither given its focal length and
        principal point are both fitted (see "Perspective" in the module docstring), and where the
        tracks carry no measurable perspective the weak-perspective fit is reported, as with
        ``image_size``. It costs a perspective fit after the weak one: on close footage about the time
        of a fit given the intrinsics; where the weak fit already explains the tracks and its perspective
        refit measures nothing (a far camera), about 1.2 times the weak fit's time on up to 100 frames
        and 1.4 times on more (the weak fit that starts it sees 100 of them, and the one reported all).
        False: weak perspective (``intrinsics`` and ``image_size`` must then be None).
    search_ties
        Also search beyond the fit's own candidates for motions that fit the tracks as well (depth flips
        refitted to the tracks, the best other continuous branch frame by frame, restarts with each joint
        shifted by ``uncertainty.SHAKE_DEG`` and ``SHAKE_FAR_DEG`` (and half a turn), from the reported fit
        and the two runners-up; on a long sequence the restarts run on about ``uncertainty.SHAKE_FRAMES``
        sampled frames), and report those found in ``alternatives``/``ambiguous``. On by default: without it, of
        384 full-range runs through a weak camera (30 frames) 10 kept a joint 2-153 degrees off reported
        observable (a basin the fit's candidates do not reach), with it 1 (docs/benchmarks.md). False
        saves its cost: a 30-frame fit takes about 1.3 times as long with it, a 300-frame one 1.2-1.3
        times. The reported motion is the same either way.

    Returns
    -------
    JointFit
        ``observable``/``relative`` follow the rule in the module docstring; ``message`` names the
        joints that are not (fully) observable and why.
    """
    if view_from not in ("above", "below", None):
        raise DescriptionError(f"view_from must be 'above', 'below' or None, not {view_from!r}")
    if accel_std is not None and not _positive(accel_std):
        raise DescriptionError(f"accel_std must be a positive number of rad/s^2 or None, not {accel_std!r}")
    if jerk_std is not None and not _positive(jerk_std):
        raise DescriptionError(f"jerk_std must be a positive number of rad/s^3 or None, not {jerk_std!r}")
    if speed_decay_s is not None and not _positive(speed_decay_s):
        raise DescriptionError(f"speed_decay_s must be a positive number of seconds or None, not {speed_decay_s!r}")
    if not _positive(fps):
        raise DescriptionError(f"fps must be positive, not {fps!r}")
    if camera not in ("static", "per-frame"):
        raise DescriptionError(f"camera must be 'static' or 'per-frame', not {camera!r}")
    if transform not in ("similarity", "rigid", "none"):
        raise DescriptionError(f"transform must be 'similarity', 'rigid' or 'none', not {transform!r}")
    if not (isinstance(max_iter, (int, np.integer)) and max_iter > 0):
        raise DescriptionError(f"max_iter must be a positive integer, not {max_iter!r}")
    if not (is_real(tol) and tol >= 0):
        raise DescriptionError(f"tol must be a finite number >= 0, not {tol!r}")
    if loss_scale_px is not None and not (is_real(loss_scale_px) and loss_scale_px >= 0):
        raise DescriptionError(f"loss_scale_px must be a finite number of pixels >= 0 or None, not {loss_scale_px!r}")
    if intrinsics is not None and not hasattr(intrinsics, "K") and hasattr(intrinsics, "image_size"):
        image_size, intrinsics = intrinsics.image_size, None  # a camera that knows its image but not its focal
    if perspective not in (None, True, False):
        raise DescriptionError(f"perspective must be None, True or False, not {perspective!r}")
    if perspective is False and (intrinsics is not None or image_size is not None):
        raise DescriptionError("perspective=False fits weak perspective: give no intrinsics or image_size with it")
    if intrinsics is not None or image_size is not None or perspective:
        def once(a_std, j_std):
            return _fit_perspective(rec_or_poses, urdf, chain, tracks, confidence, camera, refine, transform, max_iter,
                                    tol, loss_scale_px, mirror, view_from, fps, a_std, speed_decay_s, intrinsics,
                                    image_size, search_ties, jerk_std=j_std)
    else:
        def once(a_std, j_std):
            return _fit_weak(rec_or_poses, urdf, chain, tracks, confidence, camera, refine, transform, max_iter, tol,
                             loss_scale_px, mirror, view_from, fps, a_std, j_std, speed_decay_s, search_ties, _starts,
                             _assess)
    fit = once(accel_std, jerk_std)
    if _starts is not None:  # a perspective fit's starts: that fit checks its own answer's prior
        return fit
    return _prior_matched(fit, once)


def _prior_matched(fit: JointFit, once) -> JointFit:
    """``fit``, or where its motion conflicts with the motion prior it was fitted under
    (:func:`chainspace.robot.solver.prior_conflict`) the fit ``once(accel_std, jerk_std)`` made again under
    priors widened to twice the fitted motion's own rates (up to :data:`MAX_WIDENINGS` times), with a note.

    Why: the priors' defaults suit a robot at work filmed at the given fps (the benchmarks' motions
    accelerate at up to 7 rad/s^2 RMS). A faster motion, or too low an fps, makes the prior pull every joint
    towards a slower motion that the tracks do not support, and the standard deviations, taken under the
    same prior, do not show it: the robot-from-video tutorial's milling contour (12 frames at 30 fps,
    accelerations of 35-44 rad/s^2 RMS) came out 2-11 degrees off with deviations of 0.6-2.4, though the true
    motion reprojects to 0.03 px; fitted under the widened priors, 0.04-0.4 degrees off."""
    from .solver import prior_conflict

    asked, first = (fit.accel_std, fit.jerk_std), None
    for _ in range(MAX_WIDENINGS):
        ratio, rates = prior_conflict(fit.angles, fit.fps, fit.accel_std, fit.jerk_std)
        if ratio <= PRIOR_CONFLICT:
            break
        first = first or ratio
        accel_std, jerk_std = (None if std is None else max(std, 2.0 * rate)
                               for std, rate in zip((fit.accel_std, fit.jerk_std), rates))
        stage("robot fit: the motion is %.0f times faster than the motion prior allows: again, under wider priors",
              ratio)
        fit = once(accel_std, jerk_std)
    if first:
        ratio, (a0, j0) = first, asked

        def priors(a, j):
            return f"accel_std={a:.3g} rad/s^2" + ("" if j is None else f", jerk_std={j:.3g} rad/s^3")

        fit.message += (f"; the motion moved {ratio:.0f} times faster than the motion prior allows "
                        f"({priors(a0, j0)} at {fit.fps:g} fps): fitted again under "
                        f"{priors(fit.accel_std, fit.jerk_std)} (check fps)")
    return fit


def _fit_weak(rec_or_poses, urdf, chain, tracks, confidence, camera, refine, transform, max_iter, tol, loss_scale_px,
              mirror, view_from, fps, accel_std, jerk_std, speed_decay_s, search_ties, _starts, _assess) -> JointFit:
    """:func:`fit_joint_angles` through a weak-perspective camera, its options checked."""
    poses, chain, urdf, tracks, confidence = _inputs(rec_or_poses, urdf, chain, tracks, confidence)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    robot = RobotKinematics(urdf, chain)
    F = len(poses)
    per_frame = camera == "per-frame"
    w3 = _weights(poses, confidence)
    if not (w3 > 0).any():
        raise TrackError("no point of any frame is usable (all NaN or zero confidence)")
    Xz = np.nan_to_num(poses)

    # ---- step 1: 3D, both mirror images. Blind directions are known before fitting.
    blind, gauge0 = _structural(robot, w3)
    unseen3 = _unseen(robot, w3)
    _, free_blind = _hold(robot, np.broadcast_to(robot.q_rest, (F, robot.nq)), blind, blind & False, False,
                          unseen3)
    free_sim = np.array([transform != "none"] * 3 + [transform == "similarity"] + [transform != "none"] * 3)
    signs = (1.0, -1.0) if mirror and transform == "similarity" else (1.0,)
    # a perspective fit's weak start may see only some of the frames (_start_stride): its own count is said
    stage("%s, %d frames: the 3D points (%d mirror image%s)", "robot fit" if _starts is None else "weak start", F,
          len(signs), "s" if len(signs) > 1 else "")
    candidates, n_iter = _mirror_candidates(robot, Xz, w3, signs, blind, gauge0, free_blind, free_sim, unseen3,
                                            transform, max_iter, max_iter if tracks is None or not refine else 10, tol)
    mirror_tied = len(candidates) > 1 and candidates[1]["rms"] <= 1.5 * candidates[0]["rms"] + 1e-12
    best = candidates[0]
    gauge = best["gauge"]
    timings["fit_3d"] = time.perf_counter() - t0

    # ---- step 2: refine on the tracks; both mirrors unless the 3D fit told them apart clearly
    residual_px = cams = ts2 = None
    trust: dict = {}  # q_std, noise_px, alternatives, ambiguous (with tracks; chainspace.robot.uncertainty)
    side_ok = True  # whether the camera-side rule applies (set with the tracks: selection.view_side_valid)
    smoothed = False  # by the acceleration prior, which also fills the frames where a direction is unseen
    converged = best["conv"]
    if refine and tracks is not None:
        t1 = time.perf_counter()
        w2 = _weights(tracks, confidence)
        if (w2 > 0).sum() < 6:
            raise TrackError(f"the tracks have {int((w2 > 0).sum())} usable points; the camera needs at least 6")
        # only the starts of a perspective fit with the intrinsics known (never reported, not assessed):
        # that fit chooses every frame's branch again under its own camera (PerspectiveRefinement.finish)
        # and picks among exact twins itself (the wrist twins enter its candidates), so the choices
        # that serve a reported weak fit are cut short (docs/benchmarks.md, Robot fit speed, stop 49)
        weak = WeakRefinement(robot, tracks, w2, w3, blind, free_blind, gauge0, free_sim, unseen3,
                              per_frame=per_frame, transform=transform, max_iter=max_iter, tol=tol,
                              loss_scale_px=loss_scale_px, view_from=view_from, for_starts=_starts is not None,
                              starts_only=_starts is not None and not _assess, timings=timings)
        side_ok, unseen2 = weak.side_ok, weak.unseen2
        results, mirror_tied = weak.search(candidates)
        timings["refine_candidates"] = time.perf_counter() - t1
        r, results, mirror_tied, prior, sigma, scored = weak.choose(results, mirror_tied, accel_std, fps,
                                                                    speed_decay_s, jerk_std)
        smoothed = prior is not None
        if smoothed:
            timings["smoothed_choice"] = time.perf_counter() - t1 - timings["refine_candidates"]
        if _starts is not None:  # the winner first, then the alternatives: the perspective fit's starts
            _starts.extend(dict(q=x["out"][0], view=x["out"][1], free=x["free"], free_prior=x["free_prior"],
                                delta=x["delta"], gauge=x["g2"], blind=blind, px_floor=weak.px_floor)
                           for x in results)
        (q, view, rn, pos_base, conv2, _), best, gauge = r["out"], r["c"], r["g2"]
        t2 = time.perf_counter()
        # (not for the weak start of a pinhole fit with known intrinsics, which is assessed itself)
        trust = weak.assess(r, results, prior, sigma, scored, gauge, search_ties, _starts is None) if _assess else {}
        timings["uncertainty"] = time.perf_counter() - t2
        n_iter += weak.n_iter
        converged = conv2  # the 3D stage only started this one
        residual_px = _rms_per_frame(rn, w2)
        cams = view.matrices()
        ts2 = view.T[view.cam_of].copy()
        timings["refine_2d"] = time.perf_counter() - t1
    else:
        q, pos_base = best["q"], best["pos"]
    unseen = unseen2 if refine and tracks is not None else unseen3
    if not smoothed and (unseen & ~blind).any():  # the solvers held these; the neighbours' values, interpolated
        q = _fill_unseen(robot, q, unseen & ~(blind | gauge))
        pos_base = robot.positions(q)

    # ---- report in the reconstruction's frame: X = s R x + t (the mirror folded into R)
    X = best["sign"] * Xz
    if transform == "none":
        s, R, t = 1.0, np.eye(3), np.zeros(3)
    else:
        s, R, t = similarity_align(pos_base, X, w3)
        s = s if transform == "similarity" else 1.0
    R, t = best["sign"] * R, best["sign"] * t
    positions = s * pos_base @ R.T + t
    residual_3d = _rms_per_frame(np.linalg.norm(positions - Xz, axis=-1), w3)
    # one flag per degree of freedom (nv), as joint_names: a continuous joint's (cos, sin) is one angle
    observable = ~(blind | gauge)
    relative = gauge & ~blind & (not per_frame)
    notes = _notes(robot, blind, gauge & ~blind, per_frame)
    if residual_px is not None and (_starts is None or _assess):  # (a start's: the perspective fit names its own)
        notes += _face_on_notes(robot, q, view)
    notes += trust.get("notes", [])
    if _starts is None and any(n.startswith("poor fit: ") for n in notes):
        # a user's own weak-perspective fit: close-range footage is the common cause (issue 17's pinhole
        # rows fitted this way were 10-160 degrees off), and the remedy is an option away
        notes.append(PERSPECTIVE_HINT)
    msg = "; ".join(notes) if notes else "all joints observable"
    if mirror_tied:
        msg += ("; the motion and its mirror image fit the data equally well (weak perspective): "
                + (f"the one seen from {view_from} the base plane is reported" if refine and tracks is not None
                   and view_from and side_ok else "the one nearer the rest pose is reported" if side_ok else
                   "the camera side decides nothing here, so the reported one is a guess"))
    converged = np.broadcast_to(np.asarray(converged, bool), (F,)).copy()
    if not converged.all():
        msg = "the solver stopped before it converged; " + msg
        warnings.warn(f"fit_joint_angles: {msg}", ConvergenceWarning, stacklevel=2)
    timings["total"] = time.perf_counter() - t0
    return JointFit(
        q=q, joint_names=list(robot.joint_names), observable=observable, positions=positions,
        residual_3d=residual_3d, residual_px=residual_px, converged=converged, scale=float(s), rotation=R,
        translation=t, cameras=cams, translations_2d=ts2, chain=chain, urdf_path=urdf,
        message=msg, n_iter=int(n_iter), relative=relative,
        tracks=tracks, confidence=confidence, positions_base=pos_base, input_poses=poses, timings=timings,
        q_std=trust.get("q_std"), noise_px=trust.get("noise_px"), alternatives=trust.get("alternatives", []),
        ambiguous=trust.get("ambiguous", np.zeros(robot.nv, bool)), joint_reasons=trust.get("reasons", []),
        fps=float(fps), accel_std=accel_std if smoothed else None, jerk_std=jerk_std if smoothed else None,
    )


def _fit_perspective(rec_or_poses, urdf, chain, tracks, confidence, camera, refine, transform, max_iter, tol,
                     loss_scale_px, mirror, view_from, fps, accel_std, speed_decay_s, intrinsics,
                     image_size, search_ties=True, start_stride: int | None = None, *,
                     jerk_std: float | None) -> JointFit:
    """fit_joint_angles with a pinhole camera (module docstring, "Perspective"); its weak start on every
    ``start_stride``-th frame (None: :func:`_start_stride`)."""
    from ..cameras.pinhole import PinholeCamera, as_camera
    from .perspective import refine_perspective

    if camera != "static":
        raise DescriptionError("a pinhole camera (intrinsics or image_size) is fitted as one static camera: use "
                               "camera='static'")
    if not refine:
        raise DescriptionError("intrinsics / image_size need refine=True (the perspective fit is on the tracks)")
    if intrinsics is None:
        cam = None
    elif hasattr(intrinsics, "K") and hasattr(intrinsics, "undistort"):
        cam = intrinsics  # a PinholeCamera, or any camera of the same duck type
    else:
        cam = as_camera(intrinsics)  # a 3x3 matrix or a calibration file
    if cam is None and image_size is not None:
        try:
            wpx, hpx = (float(v) for v in image_size)
        except (TypeError, ValueError):
            raise DescriptionError(f"image_size must be (width, height) in pixels, not {image_size!r}") from None
        if not (_positive(wpx) and _positive(hpx)):
            raise DescriptionError(f"image_size must be positive (width, height) in pixels, not {image_size!r}")
    t0 = time.perf_counter()
    poses, chain, urdf, tracks, confidence = _inputs(rec_or_poses, urdf, chain, tracks, confidence)
    if tracks is None:
        raise DescriptionError("a pinhole camera (intrinsics, image_size or perspective=True) needs the 2D tracks "
                               "(tracks=...)")
    tracks_u = cam.undistort(tracks) if cam is not None else tracks
    w2 = _weights(tracks_u, confidence)
    # on a long sequence the weak fit only gives starts, so it sees every stride-th frame (module docstring,
    # "Perspective"); with the focal unknown and every frame seen it may be the reported fit
    stride = _start_stride(w2) if start_stride is None else start_stride
    n_seen = len(range(0, len(tracks_u), stride))
    stage("robot fit through a pinhole camera: first its weak-perspective start, on %s frames",
          f"{n_seen} of {len(tracks_u)}" if n_seen < len(tracks_u) else f"all {n_seen}")

    def weak_fit(stride: int, reported: bool) -> tuple[JointFit, list]:
        """The weak-perspective fit of every stride-th frame, and its starts for this one; ``reported``: it
        may be the answer (smoothed choice among its candidates, assessed), else it only gives starts."""
        every, found = slice(None, None, stride), []
        with warnings.catch_warnings():  # the weak fit only starts this one: its convergence is not the result's
            warnings.simplefilter("ignore", ConvergenceWarning)
            fit = fit_joint_angles(poses[every], urdf, chain=chain, tracks=tracks_u[every],
                                   confidence=None if confidence is None else np.asarray(confidence)[every],
                                   camera="static", refine=True, transform=transform, max_iter=max_iter, tol=tol,
                                   loss_scale_px=loss_scale_px, mirror=mirror, view_from=view_from, fps=fps / stride,
                                   # only starts: perspective chooses among the candidates, so the weak fit's
                                   # smoothed choice among them is skipped (the perspective fit is smoothed)
                                   accel_std=accel_std if reported else None, jerk_std=jerk_std,
                                   speed_decay_s=speed_decay_s, search_ties=search_ties, _starts=found,
                                   _assess=reported)
        return fit, found

    weak, starts = weak_fit(stride, cam is None and stride == 1)
    every = slice(None, None, stride)
    robot = weak.kinematics()
    weak_msg = weak.message.removeprefix("the solver stopped before it converged; ")
    # the squared residuals of the frames it saw, scaled to all frames' observations
    weak_sse = float(np.nansum(weak.residual_px ** 2 * w2[every].sum(1))) * w2.sum() / max(w2[every].sum(), 1e-300)
    unseen = _unseen(robot, w2)
    if stride > 1:
        starts = [_spread(robot, st, len(tracks_u), stride, unseen) for st in starts]
    distinct: list = []
    for st in starts:  # the weak fit's winner and its distinct alternatives (mirror images, flips)
        if not any(_same_motion(robot, st["q"], d["q"]) for d in distinct):
            distinct.append(st)
    t1 = time.perf_counter()
    # the focal unknown and the weak fit within the tracks' own jitter: its winner alone may tell that there
    # is no perspective (refine_perspective's early stop; with the intrinsics known there is none)
    # (on the frames it saw; the jitter from every frame: a sample's is inflated by the motion between them)
    weak_fits = cam is None and camera_misfit(
        np.linalg.norm(weak.reprojected() - np.nan_to_num(tracks_u[every]), axis=-1), w2[every],
        track_jitter(tracks_u, w2))[0] <= CAMERA_MISFIT_RATIO
    best = refine_perspective(robot, distinct, tracks_u, w2, None if cam is None else cam.K, image_size, accel_std,
                              fps, speed_decay_s, unseen, max_iter, tol, weak_sse,
                              accel_std is not None, search_ties, weak_fits=bool(weak_fits), jerk_std=jerk_std)
    timings = dict(weak.timings, perspective=time.perf_counter() - t1)
    focal = best.get("focal")
    focal_std = best.get("focal_std")
    if not best["measured"]:
        if stride > 1:  # the weak fit is the answer: made again on every frame, smoothed and assessed
            weak = weak_fit(1, True)[0]
        if not weak.converged.all():
            warnings.warn(f"fit_joint_angles: {weak.message}", ConvergenceWarning, stacklevel=2)
        weak.message += "; " + best["reason"] + ": the weak-perspective fit is reported"
        weak.focal_px, weak.focal_std_px = focal, focal_std
        timings["total"] = time.perf_counter() - t0
        weak.timings = timings
        return weak
    view = best["view"]
    if cam is None:
        cam = PinholeCamera(view.f, view.f, view.c[0], view.c[1], None,
                            *((int(v) for v in image_size) if image_size is not None else (None, None)))
    q, pos_base = best["q"], best["pos"]
    residual_px = _rms_per_frame(best["rn"], w2)
    cams, ts2 = view.weak_approximation(pos_base)
    w3 = _weights(poses, confidence)
    if transform == "none":
        s, R, t = 1.0, np.eye(3), np.zeros(3)
    else:
        s, R, t = similarity_align(pos_base, np.nan_to_num(poses), w3, reflection=transform == "similarity")
        s = s if transform == "similarity" else 1.0
    positions = s * pos_base @ R.T + t
    residual_3d = _rms_per_frame(np.linalg.norm(positions - np.nan_to_num(poses), axis=-1), w3)
    # the weak fit's ambiguities are perspective's to settle: its own (trust) notes replace them
    # (and its face-on planes: their frames are the perspective fit's to name, and the weak fit may have seen
    # only every stride-th frame)
    msg = "; ".join(_face_on_notes(robot, q, view) + [m for m in weak_msg.split("; ") if not m.startswith(
        ("ambiguous: ", "poor fit: ", "uncertain: ", "not converged: ", FACE_ON_NOTE))])
    observable, relative, msg = _pinhole_observability(robot, weak, best, msg)
    said = bool(msg)  # "all joints observable" opens the message only where no note on a joint does
    tie_note = "the motion and its mirror image fit the data equally well (weak perspective)"
    if tie_note in msg:  # the weak fit's last note
        msg = msg[:msg.index(tie_note)].removesuffix("; ")
        said = bool(msg)
        if not best["settled"]:
            msg += "; " + tie_note + ", and perspective does not tell them apart either"
    if best["n_alternatives"]:
        msg += ("; perspective chose among the weak-perspective fit and its mirror/flip alternatives"
                + ("" if best["settled"] else " (within the noise: a guess)"))
    if focal is not None:
        msg += f"; focal length estimated: {focal:.1f} +- {focal_std:.1f} px"
    if best.get("centre") is not None:
        (cx, cy), (sx, sy) = best["centre"], best["centre_std"]
        msg += f"; principal point estimated: ({cx:.0f} +- {sx:.0f}, {cy:.0f} +- {sy:.0f}) px"
    trust = best["trust"]  # q_std, noise_px, alternatives, ambiguous (chainspace.robot.uncertainty)
    msg += "".join("; " + n for n in trust["notes"])
    msg = msg.removeprefix("; ") if said or trust["notes"] else "all joints observable" + msg
    converged = np.broadcast_to(np.asarray(best["conv"], bool), (len(q),)).copy()
    if stride > 1 and (not converged.all() or trust["poor"].any()):
        # the sparse start may be why (module docstring, "Perspective"): the fit again from every frame's start
        stage(f"robot fit through a pinhole camera: a joint fitted poorly from the start on 1 frame in {stride}; "
              "again from every frame")
        sparse_s = time.perf_counter() - t0
        again = _fit_perspective(rec_or_poses, urdf, chain, tracks, confidence, camera, refine, transform, max_iter,
                                 tol, loss_scale_px, mirror, view_from, fps, accel_std, speed_decay_s, intrinsics,
                                 image_size, search_ties, start_stride=1, jerk_std=jerk_std)
        again.timings.update(sparse_start=sparse_s, total=again.timings["total"] + sparse_s)
        return again
    if not converged.all():
        msg = "the solver stopped before it converged; " + msg
        warnings.warn(f"fit_joint_angles: {msg}", ConvergenceWarning, stacklevel=2)
    timings["total"] = time.perf_counter() - t0
    return JointFit(
        q=q, joint_names=weak.joint_names, observable=observable, positions=positions,
        residual_3d=residual_3d, residual_px=residual_px, converged=converged, scale=float(s), rotation=R,
        translation=t, cameras=cams, translations_2d=ts2, chain=chain, urdf_path=urdf, message=msg,
        n_iter=int(weak.n_iter + best["n_iter"]), relative=relative, tracks=tracks, confidence=confidence,
        positions_base=pos_base, input_poses=poses, timings=timings, intrinsics=cam,
        camera_pose=(view.R[0].copy(), view.t[0].copy()), focal_px=focal, focal_std_px=focal_std,
        q_std=trust["q_std"], noise_px=trust["noise_px"], alternatives=trust["alternatives"],
        ambiguous=trust["ambiguous"], joint_reasons=trust["reasons"], fps=float(fps),
        accel_std=accel_std, jerk_std=None if accel_std is None else jerk_std,
    )


def _face_on_notes(robot: RobotKinematics, q: np.ndarray, view) -> list[str]:
    """The notes on planar parts seen nearly face-on (:func:`chainspace.robot.candidates._face_on_planes`)
    in a fit of ``q`` (F, nq) through ``view`` (its cameras' third rows are the depth axes), with the
    frames where each is."""
    return [f"{FACE_ON_NOTE}{parent} lie in one plane that the camera sees within {FACE_ON_DEG:g} degrees of face-on "
            f"in frames {_frame_ranges(frames)}: there the motion can pass unseen to its mirror image in depth "
            f"({', '.join(turned)} differ), so the branch after those frames is a guess; track a point off that "
            "plane (extra_frames) to settle it"
            for parent, turned, frames in _face_on_planes(robot, q, view.R[view.cam_of][:, 2])]


def _start_stride(w: np.ndarray) -> int:
    """Every how many frames the weak fit that starts a perspective fit looks:
    at most :data:`START_FRAMES` of the frames of weights ``w`` (F, J), as evenly spread as a stride
    allows; 1 where those frames would leave a tracked point unseen (the weak fit would hold at rest the
    joints that only it shows)."""
    stride = max(1, -(-len(w) // START_FRAMES))
    return stride if ((w[::stride] > 0).any(0) == (w > 0).any(0)).all() else 1


def _spread(robot: RobotKinematics, st: dict, n_frames: int, stride: int, unseen: np.ndarray) -> dict:
    """A weak start fitted on every ``stride``-th frame, spread to all ``n_frames``: the frames between
    them filled as unseen ones are (:func:`chainspace.robot.observability._fill_unseen`: per-dof angles
    unwrapped and interpolated linearly in time), then held as on all frames
    (:func:`chainspace.robot.observability._hold`, ``unseen`` (F, nv) the directions no seen point
    moves in each frame). A static view applies to every frame as it is."""
    between = np.ones((n_frames, robot.nv), bool)
    between[::stride] = False
    q = _fill_unseen(robot, np.repeat(st["q"], stride, axis=0)[:n_frames], between)
    view = st["view"]
    view = type(view)(view.S, view.R, view.T, np.zeros(n_frames, int))
    q, free, free_prior = _hold_with_prior(robot, q, st["blind"], st["gauge"], False, unseen)
    return dict(st, q=q, view=view, free=free, free_prior=free_prior)


def _pinhole_observability(robot: RobotKinematics, weak: JointFit, best: dict,
                           msg: str) -> tuple[np.ndarray, np.ndarray, str]:
    """``observable``, ``relative`` (nv,) and the message of a perspective fit, from the joints its
    start held (:func:`chainspace.robot.perspective._pinhole_gauge`: blind ones at rest, structural
    gauges at rest in frame 0) rather than the weak fit's; ``msg`` (the weak fit's notes) with the weak
    fit's observability notes replaced by the perspective fit's own ("" where there is nothing to say).

    Why: the weak fit also holds a joint that its configuration makes a gauge, which a static pinhole
    camera sees; the perspective fit then fits it in every frame, and reporting it as seen only
    relative to frame 0 would compare and judge it as what it is not."""
    st = best["start"]
    blind = np.asarray(st["blind"], bool)
    gauge = np.asarray(st["gauge"], bool) & ~blind
    weak_notes = _notes(robot, ~weak.observable & ~weak.relative, weak.relative & ~weak.observable, False)
    notes = _notes(robot, blind, gauge, False)
    kept = [m for m in msg.split("; ") if m and m not in weak_notes and m != "all joints observable"]
    return ~(blind | gauge), gauge.copy(), "; ".join(notes + kept)
