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
   one Pinocchio Jacobian pass over the frames and small batched solves. A prior on joint
   accelerations (``accel_std``) then averages the pixel noise over neighbouring frames; its banded
   system is solved by a banded Cholesky factorisation. Where no tracked point a joint moves is seen,
   the prior alone carries the joint: between two sightings it bridges them smoothly, but before the
   first or after the last one it would carry the joint on at its last speed for ever (a straight
   ramp costs no acceleration). ``speed_decay_s`` also charges the joint's speed there, so that it
   decays with that time constant and the joint comes to rest. Off by default: over a second unseen
   neither guess wins on the benchmarks (README, robustness section; ``benchmarks/bench_hidden_ends.py``),
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
* *Seen again after a long gap.* A joint unseen for long enough to turn half a circle at the branch
  search's step bound (``_LONG_GAP`` frames), then seen again, may come back on any branch, and the
  frame that sees it again may fit a wrong one as well as the true one (a wrist seen in one frame
  after its tool was hidden for more than a second). The acceleration prior charges nothing for a
  straight ramp across the gap, so every branch of that frame, bridged to the last sighting by a
  straight line and smoothed, can score alike: of those that tie, the motion that moves least
  (the sum of squared joint steps) is kept.
* *Singularities.* Where two joint axes align (a wrist stretched straight; a 7-axis arm's upper arm
  along its first axis) only the sum of their angles is seen, and a path may continue on either
  branch. Nothing in the tracks can split them there; plan paths (and camera checks) away from them,
  as :func:`chainspace.synthesize` does.

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
(``pinocchio.buildModelFromUrdf``); lengths in metres, angles in radians, image coordinates in the
units of the tracks (pixels). Cameras map points of the robot's base frame to the image.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .chain import KinematicChain
from .errors import ConvergenceWarning, DescriptionError, DescriptionNotFoundError, TrackError, is_real

__all__ = ["JointFit", "RobotKinematics", "fit_joint_angles", "similarity_align"]


# ---------------------------------------------------------------------------------------------------
# Pinocchio model of the tracked points
# ---------------------------------------------------------------------------------------------------
class RobotKinematics:
    """The Pinocchio model of a URDF with one frame per point of a chain, in the chain's order.

    ``positions(q)`` and ``jacobians(q)`` are vectorised over frames in their interface (q is (F, nq));
    the loop over frames is Pinocchio's. Points named in ``chain.metadata["extra_frames"]``
    ({name: (parent_link, [x, y, z])}) are added as operational frames.
    """

    def __init__(self, urdf: str | Path, chain: KinematicChain) -> None:
        import pinocchio as pin

        self.pin = pin
        path = Path(urdf)
        if not path.is_file():
            raise DescriptionNotFoundError(f"URDF file {path} does not exist")
        try:
            self.model = pin.buildModelFromUrdf(str(path))
        except Exception as exc:  # Pinocchio raises plain RuntimeError/ValueError
            raise DescriptionError(f"{path}: Pinocchio cannot read this URDF: {exc}") from None
        self.urdf_path = str(path)
        self.chain = chain
        extra = dict(chain.metadata.get("extra_frames") or {})
        self.frame_ids = [int(self._frame_id(n, extra)) for n in chain.joints]
        self.data = self.model.createData()
        m = self.model
        self.nq, self.nv = m.nq, m.nv
        self.lower = np.array(m.lowerPositionLimit, dtype=float)
        self.upper = np.array(m.upperPositionLimit, dtype=float)
        # Only 1-dof joints with nq == nv (revolute, prismatic) have meaningful box limits.
        self.limited = np.zeros(self.nq, bool)
        self.idx_v = np.zeros(self.nq, int) - 1  # velocity index of each 1-dof q entry
        for j in range(1, m.njoints):
            jm = m.joints[j]
            if jm.nq == 1 and jm.nv == 1:
                self.limited[jm.idx_q] = np.isfinite(self.lower[jm.idx_q]) and np.isfinite(self.upper[jm.idx_q]) \
                    and self.upper[jm.idx_q] > self.lower[jm.idx_q]
                self.idx_v[jm.idx_q] = jm.idx_v
        self.euclidean = self.nq == self.nv
        # 1-dof revolute joints: q and q + 2 pi are the same pose
        self.revolute = np.zeros(self.nq, bool)
        for j in range(1, m.njoints):
            jm = m.joints[j]
            if jm.nq == 1 and jm.shortname().startswith(("JointModelR", "JointModelRevolute")) \
                    and "Unbounded" not in jm.shortname():
                self.revolute[jm.idx_q] = True
        q_rest = chain.metadata.get("q_rest")
        self.q_rest = self.clip(np.asarray(q_rest, float) if q_rest is not None and np.size(q_rest) == self.nq
                                else np.array(pin.neutral(m)))
        self.joint_names = self._q_names()
        # Each point as its joint's placement applies it: the parent joint, the point in its frame
        # (homogeneous), and the velocity directions that move it (J, nv): its supporting joints.
        self._parent_joint = np.array([m.frames[fid].parentJoint for fid in self.frame_ids], int)
        self._in_parent = np.array([np.append(m.frames[fid].placement.translation, 1.0) for fid in self.frame_ids])
        self._carried_by = np.zeros((len(self.frame_ids), self.nv), bool)
        for k, parent in enumerate(self._parent_joint):
            for j in m.supports[int(parent)][1:]:
                self._carried_by[k, m.joints[j].idx_v:m.joints[j].idx_v + m.joints[j].nv] = True
        # Where solvers start from "the rest pose": the rest pose with every revolute joint turned a
        # little, because rest poses are often singular (a stretched wrist, an upright arm), where the
        # gradient cannot tell a joint's sign.
        up = self.q_rest + 0.3
        seed = np.where(self.limited & (up > self.upper), self.q_rest - 0.3, up)
        self.q_seed = self.clip(np.where(self.revolute, seed, self.q_rest))
        self.q_seed_other = self.clip(2 * self.q_rest - self.q_seed)  # turned the other way
        # the velocity index driving each q entry (-1 for the extra entries of multi-dof joints)
        self.v_of_q = self.idx_v.copy()
        self.q_of_v = np.array([int(np.flatnonzero(self.idx_v == v)[0]) if (self.idx_v == v).any() else -1
                                for v in range(self.nv)])

    def _frame_id(self, name: str, extra: dict) -> int:
        pin, m = self.pin, self.model
        if name in extra:
            parent, xyz = extra[name]
            if not m.existFrame(parent):
                raise DescriptionError(
                    f"{self.urdf_path}: extra frame {name!r} hangs from {parent!r}, which is not a link of the URDF")
            pf = m.getFrameId(parent)
            frame = m.frames[pf]
            placement = frame.placement * pin.SE3(np.eye(3), np.asarray(xyz, dtype=float))
            return m.addFrame(pin.Frame(name, frame.parentJoint, pf, placement, pin.FrameType.OP_FRAME))
        if m.existFrame(name, pin.FrameType.BODY):
            return m.getFrameId(name, pin.FrameType.BODY)
        if m.existFrame(name):
            return m.getFrameId(name)
        raise DescriptionError(
            f"{self.urdf_path}: chain point {name!r} is neither a link of the URDF nor an extra frame "
            f"(extra frames: {sorted(extra) or 'none'}); build the chain with chainspace.from_urdf")

    def _q_names(self) -> list[str]:
        m, names = self.model, []
        for j in range(1, m.njoints):
            nq = m.joints[j].nq
            names += [m.names[j]] if nq == 1 else [f"{m.names[j]}[{k}]" for k in range(nq)]
        return names

    # ------------------------------------------------------------------ configuration space
    def clip(self, q: np.ndarray) -> np.ndarray:
        """Project configurations (..., nq) into the joint limits."""
        q = np.array(q, dtype=float)
        q[..., self.limited] = np.clip(q[..., self.limited], self.lower[self.limited], self.upper[self.limited])
        return q

    def wrap_near(self, q: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """Shift revolute joints of a path q (F, nq) by whole turns, the same for all frames, so that the
        first frame is nearest ref (nq,), where the limits allow: the same poses, comparable angles."""
        q = np.array(q, dtype=float)
        k = np.round((q[0] - ref) / (2 * np.pi)) * self.revolute
        for turns in (k, np.sign(k) * (np.abs(k) - 1)):
            shifted = q - 2 * np.pi * turns
            ok = ~self.limited | ((shifted.min(0) >= self.lower - 1e-12) & (shifted.max(0) <= self.upper + 1e-12))
            ok &= turns != 0
            q[:, ok] = shifted[:, ok]
            k = np.where(ok, 0, k)
        return q

    def continuous(self, q: np.ndarray) -> np.ndarray:
        """A path q (F, nq) without whole-turn jumps between frames: each revolute joint unwrapped along
        the frames, then moved by whole turns into its limits (the first frame's turn kept where
        possible). A joint whose unwrapped path does not fit its limits keeps its values."""
        q = np.array(q, dtype=float)
        for i in np.flatnonzero(self.revolute):
            u = np.unwrap(q[:, i])
            u -= 2 * np.pi * np.round((u[0] - q[0, i]) / (2 * np.pi))
            if self.limited[i]:
                u -= 2 * np.pi * np.ceil(max(u.max() - self.upper[i] - 1e-9, 0.0) / (2 * np.pi))
                u += 2 * np.pi * np.ceil(max(self.lower[i] - u.min() - 1e-9, 0.0) / (2 * np.pi))
                if u.min() < self.lower[i] - 1e-9 or u.max() > self.upper[i] + 1e-9:
                    continue
            q[:, i] = u
        return q

    def integrate(self, q: np.ndarray, dv: np.ndarray, clip: bool = True) -> np.ndarray:
        """q (F, nq) moved by velocities dv (F, nv), then clipped into the limits (unless not ``clip``)."""
        if self.euclidean:
            out = q + dv
        else:
            out = np.array([self.pin.integrate(self.model, qf, vf) for qf, vf in zip(q, dv)])
        return self.clip(out) if clip else out

    def angles(self, q: np.ndarray) -> np.ndarray:
        """(F, nv) per-dof coordinates: q itself for 1-dof joints; continuous joints' (cos, sin) as an
        unwrapped angle. Other multi-dof joints (spherical, free) give the difference to the rest."""
        q = np.asarray(q, float)
        if self.euclidean:
            return q.copy()
        out = np.zeros(q.shape[:-1] + (self.nv,))
        m = self.model
        for j in range(1, m.njoints):
            jm = m.joints[j]
            if jm.nq == jm.nv:
                out[..., jm.idx_v:jm.idx_v + jm.nv] = q[..., jm.idx_q:jm.idx_q + jm.nq]
            elif jm.nq == 2 and jm.nv == 1:
                out[..., jm.idx_v] = np.unwrap(np.arctan2(q[..., jm.idx_q + 1], q[..., jm.idx_q]), axis=0)
            else:
                for f in np.ndindex(q.shape[:-1]):
                    d = self.pin.difference(m, self.q_rest, q[f])
                    out[f + (slice(jm.idx_v, jm.idx_v + jm.nv),)] = d[jm.idx_v:jm.idx_v + jm.nv]
        return out

    # ------------------------------------------------------------------ kinematics
    def positions(self, q: np.ndarray) -> np.ndarray:
        """World positions (F, J, 3) of the chain's points for configurations q (F, nq), metres."""
        pin, m, d = self.pin, self.model, self.data
        q = np.atleast_2d(q)
        placements = np.empty((len(q), m.njoints, 4, 4))
        for f, qf in enumerate(q):
            pin.forwardKinematics(m, d, qf)
            placements[f] = [M.homogeneous for M in d.oMi.tolist()]
        return self._points(placements)

    def _points(self, placements: np.ndarray) -> np.ndarray:
        """The chain's points (F, J, 3) from the joints' world placements (F, njoints, 4, 4): one product
        for all points and frames, where reading each point's placement from Pinocchio takes a call."""
        return (placements[:, self._parent_joint] @ self._in_parent[..., None])[..., :3, 0]

    def jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (F, J, 3) and translational frame Jacobians (F, J, 3, nv) in world axes."""
        pin, m, d = self.pin, self.model, self.data
        q = np.atleast_2d(q)
        placements = np.empty((len(q), m.njoints, 4, 4))
        spatial = np.empty((len(q), 6, self.nv))
        for f, qf in enumerate(q):
            pin.computeJointJacobians(m, d, qf)
            spatial[f] = d.J
            placements[f] = [M.homogeneous for M in d.oMi.tolist()]
        # What pin.getFrameJacobian(LOCAL_WORLD_ALIGNED) returns: the world Jacobian's twist moved to each
        # point, on the joints that carry it; for all points and frames at once. One Pinocchio call per
        # point and frame cost more than the kinematics themselves.
        pos = self._points(placements)
        lin, ang = spatial[:, None, :3], spatial[:, None, 3:]
        return pos, (lin + np.cross(ang, pos[..., None], axis=2)) * self._carried_by[:, None]

    def reach(self) -> float:
        """Largest distance of a chain point from the root over the rest pose and the limits' middle, m."""
        qs = [self.q_rest, self.clip(np.where(self.limited, 0.5 * (self.lower + self.upper), self.q_rest))]
        p = self.positions(np.array(qs))
        return float(np.linalg.norm(p - p[:, :1], axis=-1).max())


# ---------------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------------
@dataclass
class JointFit:
    """Joint angles fitted to a robot's motion.

    q (F, nq) radians / metres in Pinocchio's order; joint_names one per q entry; observable (nq,) bool
    (False: held fixed, see the module docstring); relative (nq,) bool (seen only relative to the first
    frame); positions (F, J, 3) fitted chain points in the reconstruction's frame (metres when the
    reconstruction is); residual_3d (F,) RMS distance to the reconstructed points; residual_px (F,) RMS
    reprojection error or None; converged (F,) bool; scale, rotation (3, 3), translation (3,) the
    similarity from the robot's base frame to the reconstruction's; cameras (F, 2, 3) and
    translations_2d (F, 2) map the base frame to the image (``u = cameras[f] @ x + translations_2d[f]``).
    """

    q: np.ndarray
    joint_names: list[str]
    observable: np.ndarray
    positions: np.ndarray
    residual_3d: np.ndarray
    residual_px: np.ndarray | None
    converged: np.ndarray
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    cameras: np.ndarray | None
    translations_2d: np.ndarray | None
    chain: KinematicChain
    urdf_path: str
    message: str
    n_iter: int
    relative: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    tracks: np.ndarray | None = None
    confidence: np.ndarray | None = None
    positions_base: np.ndarray | None = None
    input_poses: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return len(self.q)

    def kinematics(self) -> RobotKinematics:
        """The Pinocchio model used by the fit (rebuilt from ``urdf_path``)."""
        return RobotKinematics(self.urdf_path, self.chain)

    def reprojected(self) -> np.ndarray | None:
        """(F, J, 2) the fitted robot seen by the fitted camera, or None without a camera."""
        if self.cameras is None or self.positions_base is None:
            return None
        return np.einsum("fij,fkj->fki", self.cameras, self.positions_base) + self.translations_2d[:, None]

    def __repr__(self) -> str:
        obs = int(self.observable.sum())
        px = "" if self.residual_px is None else f", reprojection {np.nanmean(self.residual_px):.3g} px"
        return (f"JointFit({self.n_frames} frames, {len(self.joint_names)} q entries ({obs} observable){px}, "
                f"converged {int(self.converged.sum())}/{self.n_frames}: {self.message})")


# ---------------------------------------------------------------------------------------------------
# small numerical helpers
# ---------------------------------------------------------------------------------------------------
def similarity_align(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None, *,
                     reflection: bool = False, scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama's weighted similarity ``dst ~ s R src + t`` over all points (..., 3); NaN rows ignored.

    Returns (s, R (3, 3), t (3,)). ``reflection=False`` keeps det(R) = +1; ``scale=False`` fixes s = 1
    (a rigid motion).
    """
    a = src.reshape(-1, 3)
    b = dst.reshape(-1, 3)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, float).reshape(-1).copy()
    ok = np.isfinite(a).all(1) & np.isfinite(b).all(1) & (w > 0)
    a, b, w = a[ok], b[ok], w[ok] / w[ok].sum()
    ma, mb = w @ a, w @ b
    A, B = a - ma, b - mb
    cov = (B * w[:, None]).T @ A
    U, S, Vt = np.linalg.svd(cov)
    d = np.ones(3)
    if not reflection and np.linalg.det(U @ Vt) < 0:
        d[-1] = -1
    R = U @ np.diag(d) @ Vt
    var = float(w @ (A ** 2).sum(1))
    s = float((S * d).sum() / var) if var > 0 and scale else 1.0
    return s, R, mb - s * R @ ma


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def _rotvec(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues)."""
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = _skew(w)
    small = th < 1e-8
    a = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5, (1 - np.cos(th)) / np.where(small, 1.0, th ** 2))
    return np.eye(3) + a * K + b * K @ K


def _affine_camera(x: np.ndarray, u: np.ndarray, w: np.ndarray, per_frame: bool) -> tuple[np.ndarray, np.ndarray]:
    """Weak-perspective camera(s) s R[:2] (F, 2, 3) and t (F, 2) closest to u ~ M x + t (least squares,
    then the 2x3 matrix projected onto scaled orthonormal rows)."""
    F = len(x)
    groups = [np.arange(F)[i:i + 1] for i in range(F)] if per_frame else [np.arange(F)]
    cams, ts = np.zeros((F, 2, 3)), np.zeros((F, 2))
    for g in groups:
        xs, us, ws = x[g].reshape(-1, 3), u[g].reshape(-1, 2), w[g].reshape(-1)
        ok = (ws > 0) & np.isfinite(us).all(1)
        A = np.hstack([xs[ok], np.ones((ok.sum(), 1))]) * np.sqrt(ws[ok])[:, None]
        sol = np.linalg.lstsq(A, us[ok] * np.sqrt(ws[ok])[:, None], rcond=None)[0]  # (4, 2)
        M = sol[:3].T
        U, S, Vt = np.linalg.svd(M, full_matrices=False)
        cams[g] = S.mean() * (U @ Vt)
        ts[g] = sol[3]
    return cams, ts


def _camera_view(x: np.ndarray, u: np.ndarray, w: np.ndarray, per_frame: bool) -> _View:
    """The weak-perspective camera(s) closest to u ~ P x + t, as a view for the solvers."""
    F = len(x)
    P0, t20 = _affine_camera(x, u, w, per_frame)
    views = [_camera_to_rotation(P) for P in (P0 if per_frame else P0[:1])]
    return _View(np.array([v[0] for v in views]), np.array([v[1] for v in views]),
                 t20 if per_frame else t20[:1], np.arange(F) if per_frame else np.zeros(F, int))


def _camera_to_rotation(M: np.ndarray) -> tuple[float, np.ndarray]:
    """A weak-perspective 2x3 camera s R[:2] -> (s, full rotation R)."""
    s = float(np.linalg.norm(M, axis=1).mean())
    r1, r2 = M[0] / np.linalg.norm(M[0]), M[1] / np.linalg.norm(M[1])
    r2 = r2 - (r1 @ r2) * r1
    r2 /= np.linalg.norm(r2)
    return s, np.stack([r1, r2, np.cross(r1, r2)])


# ---------------------------------------------------------------------------------------------------
# Levenberg-Marquardt over a sequence: per-frame joint angles + a shared (or per-frame) view
# ---------------------------------------------------------------------------------------------------
def _huber(rn: np.ndarray, delta: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Huber loss rho(r) and IRLS weight rho'(r) / (2 r) of residual norms (plain squares when delta is None)."""
    if delta is None:
        return rn ** 2, np.ones_like(rn)
    inside = rn <= delta
    return (np.where(inside, rn ** 2, 2 * delta * rn - delta ** 2),
            np.where(inside, 1.0, delta / np.maximum(rn, 1e-300)))


@dataclass
class _View:
    """The sequence's view of the robot's base frame: ``target ~ S[c] (R[c] x)[:D] + T[c]`` for the view
    c = cam_of[f] of frame f. D = 3: a similarity onto 3D points; D = 2: weak-perspective cameras."""

    S: np.ndarray  # (C,) scale
    R: np.ndarray  # (C, 3, 3) rotation
    T: np.ndarray  # (C, D) translation
    cam_of: np.ndarray  # (F,) view index of each frame

    @staticmethod
    def identity(n_frames: int) -> _View:
        """One view that leaves base-frame points as they are (3D targets in the base frame)."""
        return _View(np.ones(1), np.eye(3)[None], np.zeros((1, 3)), np.zeros(n_frames, int))

    @property
    def per_frame(self) -> bool:
        return len(self.S) == len(self.cam_of) and len(self.S) > 1

    def apply(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(prediction (F, J, D), rotated points y = R x (F, J, 3))."""
        c = self.cam_of
        y = np.einsum("fij,fkj->fki", self.R[c], x)
        D = self.T.shape[1]
        return self.S[c][:, None, None] * y[..., :D] + self.T[c][:, None], y

    def moved(self, dc: np.ndarray) -> _View:
        """The view after a step dc (C, 3 + 1 + D): rotation vector (R <- exp(w^) R), scale, translation."""
        return _View(self.S + dc[:, 3], np.einsum("cij,cjk->cik", _rotvec(dc[:, :3]), self.R),
                     self.T + dc[:, 4:], self.cam_of)

    def take(self, idx: np.ndarray) -> _View:
        """The view of frames idx only."""
        if self.per_frame:
            return _View(self.S[idx], self.R[idx], self.T[idx], np.arange(len(idx)))
        return _View(self.S, self.R, self.T, self.cam_of[idx])

    def put(self, idx: np.ndarray, sub: _View, accept: np.ndarray) -> _View:
        """This view with the frames idx[accept] taken from sub (a view from take(idx))."""
        if not accept.any():
            return self
        if not self.per_frame:
            return _View(sub.S, sub.R, sub.T, self.cam_of)
        S, R, T = self.S.copy(), self.R.copy(), self.T.copy()
        S[idx[accept]], R[idx[accept]], T[idx[accept]] = sub.S[accept], sub.R[accept], sub.T[accept]
        return _View(S, R, T, self.cam_of)

    def matrices(self) -> np.ndarray:
        """(F, D, 3) the linear part s R[:D] per frame."""
        c = self.cam_of
        return self.S[c][:, None, None] * self.R[c][:, : self.T.shape[1]]


def _normal_equations(view: _View, jac: np.ndarray, y: np.ndarray, res: np.ndarray, ww: np.ndarray,
                      free: np.ndarray, free_view: np.ndarray):
    """Gauss-Newton blocks of the weighted residuals res (F, J, D) = S (R x)[:D] + T - target.

    jac (F, J, 3, nv) point Jacobians, y = R x (F, J, 3), ww (F, J) IRLS weights. Returns per frame
    Hqq (F, nv, nv), Hqc (F, nv, nc), gq (F, nv) and per view Hcc (C, nc, nc), gc (C, nc); view
    parameters: rotation vector, scale, translation (nc = 4 + D).
    """
    F, J, D = res.shape
    sc = view.S[view.cam_of][:, None, None, None]
    Jq = (view.matrices()[:, None] @ jac * free[:, None, None, :]).reshape(F, J * D, -1)
    Jc = (np.concatenate([-sc * _skew(y)[..., :D, :], y[..., :D, None],
                          np.broadcast_to(np.eye(D), (F, J, D, D))], -1) * free_view).reshape(F, J * D, -1)
    # batched products over the stacked (point, axis) rows: einsum's three-operand loops were the
    # solver's main cost after the kinematics
    JqW = (Jq * np.repeat(ww, D, axis=1)[..., None]).transpose(0, 2, 1)
    JcW = (Jc * np.repeat(ww, D, axis=1)[..., None]).transpose(0, 2, 1)
    r = res.reshape(F, J * D, 1)
    Hqq, Hqc, gq = JqW @ Jq, JqW @ Jc, (JqW @ r)[..., 0]
    C, nc = len(view.S), 4 + D
    Hcc, gc = np.zeros((C, nc, nc)), np.zeros((C, nc))
    np.add.at(Hcc, view.cam_of, JcW @ Jc)
    np.add.at(gc, view.cam_of, (JcW @ r)[..., 0])
    return Hqq, Hqc, gq, Hcc, gc


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
    L = sp.diags([np.ones(F - 2), -2 * np.ones(F - 2), np.ones(F - 2)], [0, 1, 2], shape=(F - 2, F))
    D1 = sp.kron(sp.diags([-np.ones(F - 1), np.ones(F - 1)], [0, 1], shape=(F - 1, F)), sp.eye(nv))
    speed = sp.diags(_beyond_sightings(unseen).reshape(-1) * (mu / decay_frames ** 2))
    return (sp.kron(mu * (L.T @ L), sp.eye(nv)) + D1.T @ speed @ D1).tocsr()


def _smoothed_objective(prior, q: np.ndarray, rn: np.ndarray, w: np.ndarray, delta: float | None) -> float:
    """What :func:`_smooth_lm` minimises: robust residuals (norms rn (F, J), weights w, Huber threshold
    delta) plus the motion prior q' prior q'."""
    qf = q.reshape(-1)
    return float((w * _huber(rn, delta)[0]).sum()) + float(qf @ (prior @ qf))


def _smooth_lm(robot: RobotKinematics, q: np.ndarray, target: np.ndarray, w: np.ndarray, view: _View,
               free: np.ndarray, free_view: np.ndarray, max_iter: int, tol: float, delta: float | None,
               prior):
    """Levenberg-Marquardt of :func:`_sequence_lm` for one shared view, plus a quadratic prior on the
    motion, q' prior q' with q' the (F nv,) joint angles frame after frame (:func:`_motion_prior`),
    that couples neighbouring frames.

    The joint-angle block of the normal equations is then banded (two frames either side); it is
    factored as a banded Cholesky (scipy.linalg.cholesky_banded) and the view eliminated by a
    Schur complement, so an iteration stays linear in the number of frames. Same returns.
    """
    from scipy.linalg import cho_solve_banded, cholesky_banded

    F, J, D = target.shape
    nv, nc = robot.nv, 4 + D
    N = F * nv
    u = 3 * nv - 1  # upper bandwidth: frame f couples to f + 2
    tz = np.nan_to_num(target)
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
        pos, jac = robot.jacobians(q)
        pred, y = view.apply(pos)
        res = pred - tz
        return pos, jac, y, res, _smoothed_objective(prior, q, np.linalg.norm(res, axis=-1), w, delta)

    pos, jac, y, res, cost = evaluate(q, view)
    lam, converged, it = 1e-4, False, 0
    for it in range(1, max_iter + 1):
        ww = w * _huber(np.linalg.norm(res, axis=-1), delta)[1]
        Hqq, Hqc, gq, Hcc, gc = _normal_equations(view, jac, y, res, ww, free, free_view)
        gq = gq.reshape(-1) + prior @ q.reshape(-1)
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
        pos, jac, y, res, cost = trial
        lam = max(lam / 5, 1e-12)
        if rel < tol or cost < 1e-24:
            converged = True
            break
    return q, view, np.linalg.norm(res, axis=-1), pos, np.full(F, converged), it


def _sequence_lm(robot: RobotKinematics, q: np.ndarray, target: np.ndarray, w: np.ndarray, view: _View,
                 free: np.ndarray, free_view: np.ndarray, max_iter: int, tol: float, delta: float | None):
    """Levenberg-Marquardt on all frames' joint angles and the view(s) against target (F, J, D).

    The normal equations have one (nv x nv) block per frame and one small block per view; the views are
    eliminated by a Schur complement (batched over frames), so an iteration costs one Pinocchio Jacobian
    pass and small batched solves. When the frames are independent (the view fixed, or one view per
    frame) each frame keeps its own damping and accepts its own steps, and converged frames drop out.
    free (F, nv) / free_view (3 + 1 + D,) mask the directions allowed to move; a robust Huber loss
    (IRLS) with threshold delta (None: squares). Returns (q, view, residual norms (F, J), base-frame
    positions (F, J, 3), converged (F,), iterations).
    """
    F, J, D = target.shape
    nv, nc = robot.nv, 4 + D
    tz = np.nan_to_num(target)
    eye_q, eye_c = np.eye(nv), np.eye(nc)
    fixed_q, fixed_c = (~free).astype(float), (~free_view).astype(float)
    independent = not free_view.any() or view.per_frame
    q = q.copy()

    def evaluate(qa, va, a):
        pos, jac = robot.jacobians(qa)
        pred, y = va.apply(pos)
        res = pred - tz[a]
        return pos, jac, y, res, (w[a] * _huber(np.linalg.norm(res, axis=-1), delta)[0]).sum(1)

    pos, jac, y, res, cost = evaluate(q, view, np.arange(F))
    lam = np.full(F, 1e-4)
    active = np.ones(F, bool)
    it = 0
    for it in range(1, max_iter + 1):
        a = np.flatnonzero(active)
        va = view.take(a)
        ww = w[a] * _huber(np.linalg.norm(res[a], axis=-1), delta)[1]
        Hqq, Hqc, gq, Hcc, gc = _normal_equations(va, jac[a], y[a], res[a], ww, free[a], free_view)
        Ca = len(va.S)
        dq_diag = np.einsum("fvv->fv", Hqq)
        dc_diag = np.einsum("cdd->cd", Hcc)
        floor_q = 1e-6 * dq_diag.mean(1, keepdims=True) + 1e-30
        for _ in range(1 if independent else 12):
            la = lam[a]
            Hq = Hqq + (la[:, None] * (dq_diag + floor_q) + fixed_q[a])[:, :, None] * eye_q
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
            p_t, j_t, y_t, r_t, c_t = evaluate(q_t, v_t, a)
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
        q[b], pos[b], jac[b], y[b], res[b], cost[b] = q_t[better], p_t[better], j_t[better], y_t[better], \
            r_t[better], c_t[better]
        view = view.put(a, v_t, better)
        lam[b] = np.maximum(lam[b] / 5, 1e-12)
        lam[a[~better]] *= 10
        done = (rel < tol) | (cost[b] < 1e-24)
        if independent:
            active[b[done]] = False
            active[a[~better][lam[a[~better]] > 1e10]] = False
        elif done.all():
            active[:] = False
        if not active.any():
            break
    return q, view, np.linalg.norm(res, axis=-1), pos, ~active, it


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


# ---------------------------------------------------------------------------------------------------
# step 1: joint angles and one similarity from 3D points
# ---------------------------------------------------------------------------------------------------
def _align(x: np.ndarray, X: np.ndarray, w: np.ndarray, transform: str) -> _View:
    """The sequence's similarity (or rigid motion, or identity) from base-frame points x onto X."""
    if transform == "none":
        s, R, t = 1.0, np.eye(3), np.zeros(3)
    else:
        s, R, t = similarity_align(np.broadcast_to(x, X.shape), X, w)
        s = s if transform == "similarity" else 1.0
    return _View(np.array([s]), R[None], t[None], np.zeros(len(X), int))


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


def _branch_near_rest(robot: RobotKinematics, Y: np.ndarray, w: np.ndarray, view: _View, free: np.ndarray,
                      q_now: np.ndarray, gauge: np.ndarray, n_seeds: int = 48, seed: int = 0) -> np.ndarray:
    """Of the joint angles that fit one frame's points Y (J, 3) equally well, the nearest the rest pose.

    Tracked points on joint axes leave discrete ambiguities (a wrist turned half a turn with the next
    joint mirrored puts every point in the same place); the data cannot choose, so the branch of the
    rest pose is taken, found by IK from many seeds.
    """
    rng = np.random.default_rng(seed)
    seeds = _random_q(robot, rng, n_seeds) if robot.euclidean else np.broadcast_to(robot.q_rest, (n_seeds, robot.nq))
    seeds = np.concatenate([robot.q_rest[None], robot.q_seed[None], q_now[None], seeds])
    seeds[:, ~free] = q_now[~free] if robot.euclidean else seeds[:, ~free]
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


def _rest_distance(robot: RobotKinematics, q: np.ndarray, q_prev: np.ndarray, gauge: np.ndarray) -> np.ndarray:
    """Summed absolute joint offsets (wrapped) of q (N, nq) from the rest pose; gauge joints (whose
    absolute value the view absorbs) count from q_prev instead."""
    ref = np.where(_gauge_q(robot, gauge), q_prev, robot.q_rest)
    return np.abs(_wrapped(robot, q - ref)).sum(-1)


def _gauge_q(robot: RobotKinematics, gauge_v: np.ndarray) -> np.ndarray:
    """(nq,) mask of the q entries driven by the velocity directions gauge_v (nv,)."""
    out = np.zeros(robot.nq, bool)
    qi = robot.q_of_v[gauge_v]
    out[qi[qi >= 0]] = True
    return out


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
    for a in range(0, F, block):
        idx = np.arange(a, min(a + block, F))
        n = len(idx)
        both = np.concatenate([idx, idx])
        alt = _seeded(robot, np.broadcast_to(prev, (n, robot.nq)), free[idx]) if q_alt is None else q_alt[idx]
        q0 = np.concatenate([np.broadcast_to(prev, (n, robot.nq)), alt])
        qs, _, rn, _, _, _ = _sequence_lm(robot, q0, X[both], w[both], view.take(both), free[both],
                                          np.zeros(4 + X.shape[-1], bool), 30, 1e-8, None)
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


def _seeded(robot: RobotKinematics, q: np.ndarray, free: np.ndarray, other_side: bool = False) -> np.ndarray:
    """Start configurations (F, nq): the solver seed near the rest pose (or the one turned the other
    way) where a direction is free, the current q where it is held."""
    return np.where(_held_q(robot, free), q, robot.q_seed_other if other_side else robot.q_seed)


def _held_q(robot: RobotKinematics, free: np.ndarray) -> np.ndarray:
    """(..., nq) entries of q held where free (..., nv) holds their direction."""
    held = np.zeros(free.shape[:-1] + (robot.nq,), bool)
    vq = robot.v_of_q >= 0
    held[..., vq] = ~free[..., robot.v_of_q[vq]]
    return held


def _random_q(robot: RobotKinematics, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, nq) configurations drawn uniformly within the joint limits (a turn either way where none)."""
    lo = np.where(robot.limited, np.maximum(robot.lower, -np.pi), -np.pi)
    hi = np.where(robot.limited, np.minimum(robot.upper, np.pi), np.pi)
    return robot.clip(rng.uniform(lo, hi, (n, robot.nq)))


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
    F, nq = q.shape
    rng = np.random.default_rng(seed)
    held_q = _held_q(robot, free)  # entries held in a frame keep their value in every start
    rand = _random_q(robot, rng, n_random) if robot.euclidean else np.broadcast_to(robot.q_rest, (n_random, nq))
    starts = [q, _seeded(robot, q, free), _seeded(robot, q, free, True)] + [np.where(held_q, q, r) for r in rand] + \
        [np.where(held_q, q, m) for m in _depth_flips(robot, q, view, free)]
    K = len(starts)
    q0 = np.concatenate(starts)
    idx = np.tile(np.arange(F), K)
    qs, _, rn, _, _, _ = _sequence_lm(robot, q0, target[idx], w[idx], view.take(idx), free[idx],
                                      np.zeros(4 + target.shape[-1], bool), 30, 1e-8, None)
    qs = qs.reshape(K, F, nq)
    data = (w[idx] * rn ** 2).sum(1).reshape(K, F) / max(sigma, 1e-12) ** 2
    data += 0.05 * np.abs(_wrapped(robot, qs - robot.q_rest)).sum(-1)
    back = np.zeros((F, K), int)
    acc = data[:, 0].copy()
    for f in range(1, F):  # a loop over frames: the recursion is sequential, each step is (K, K)
        jump = np.linalg.norm(_wrapped(robot, qs[None, :, f] - qs[:, None, f - 1]), axis=-1)  # (from, to)
        trans = (np.maximum(jump - free_step, 0.0) / step) ** 2
        tot = acc[:, None] + trans
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
                                          np.zeros(4 + tracks.shape[-1], bool), 30, 1e-8, None)
        sse = (w[b] * rn ** 2).sum(1)
        kept: list[np.ndarray] = []
        for k in np.argsort(sse):
            if sse[k] > sse.min() + 25.0 * sigma ** 2:
                break
            if any(np.abs(_wrapped(robot, qs[k] - o)).max() < 0.05 for o in kept + [q[b]]):
                continue
            kept.append(qs[k])
            bridged = robot.continuous(q.copy())
            bridged[b] = robot.wrap_near(qs[k][None], bridged[b - 1])[0]
            for v in np.flatnonzero(runs[b - 1] >= min_gap):
                qi = robot.q_of_v[v]
                a = b - runs[b - 1, v]
                if qi >= 0 and a > 0:
                    bridged[a:b, qi] = np.linspace(bridged[a - 1, qi], bridged[b, qi], b - a + 2)[1:-1]
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
    n = view.R[view.cam_of][:, 2]  # (F, 3) the camera's depth axis in the base frame
    index = {name: i for i, name in enumerate(robot.chain.joints)}
    mirrored = []
    for b, (parent, _) in enumerate(robot.chain.bones):
        beyond = robot.chain.D[b] != 0
        m, depth = _mirrored_beyond(pos, beyond, index[parent], n)
        if np.abs(depth).max() < 1e-9:
            continue
        mirrored.append(m)
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
    qs = _sequence_lm(robot, np.concatenate(starts), np.concatenate(targets), np.ones((K * F, pos.shape[1])), eye,
                      np.tile(free, (K, 1)), np.zeros(7, bool), 30, 1e-8, None)[0]
    return list(qs.reshape(K, F, -1))


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
            turned = np.abs(_wrapped(robot, q_m - q))[reached].max(0) > 1e-3
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


def _roughness(robot: RobotKinematics, q: np.ndarray) -> float:
    """Sum of squared joint steps between frames (wrapped), rad^2: large where a path jumps branches."""
    return float((_wrapped(robot, np.diff(q, axis=0)) ** 2).sum())


def _wrapped(robot: RobotKinematics, dq: np.ndarray) -> np.ndarray:
    """Differences of configurations with revolute joints wrapped into [-pi, pi)."""
    return np.where(robot.revolute, (dq + np.pi) % (2 * np.pi) - np.pi, dq)


# ---------------------------------------------------------------------------------------------------
# observability
# ---------------------------------------------------------------------------------------------------
def _structural(robot: RobotKinematics, w: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """What the tracked points (those with weight somewhere in w (F, J)) can see, from the structure
    alone: at a few random configurations, the (nv,) directions that move no tracked point (blind) and
    those a change of the sequence's similarity imitates (gauge)."""
    rng = np.random.default_rng(seed)
    lo = np.where(robot.limited, robot.lower, -np.pi)
    hi = np.where(robot.limited, robot.upper, np.pi)
    qs = robot.clip(np.where(robot.v_of_q >= 0, rng.uniform(lo, hi, (3, robot.nq)), robot.q_rest))
    pos, jac = robot.jacobians(qs)
    seen = (w > 0).any(0)
    ext = max(np.linalg.norm(pos[:, seen] - pos[:, seen].mean(1, keepdims=True), axis=-1).max(), 1e-9)
    blind = np.linalg.norm(jac[:, seen], axis=2).max(axis=(0, 1)) < 1e-9 * ext
    gauge = _gauge_directions(pos[:, seen], jac[:, seen], np.ones((3, seen.sum())), None, False) & ~blind
    return blind, gauge


def _unseen(robot: RobotKinematics, w: np.ndarray, seed: int = 0) -> np.ndarray:
    """(F, nv) directions that move no point seen in that frame (w (F, J) > 0): the data say nothing
    about them there, so they are held and later interpolated from the neighbouring frames."""
    rng = np.random.default_rng(seed)
    lo = np.where(robot.limited, robot.lower, -np.pi)
    hi = np.where(robot.limited, robot.upper, np.pi)
    qs = robot.clip(np.where(robot.v_of_q >= 0, rng.uniform(lo, hi, (3, robot.nq)), robot.q_rest))
    pos, jac = robot.jacobians(qs)
    ext = max(np.linalg.norm(pos - pos.mean(1, keepdims=True), axis=-1).max(), 1e-9)
    moves = np.linalg.norm(jac, axis=2).max(0) > 1e-9 * ext  # (J, nv) structural support
    return ~((w > 0).astype(float) @ moves.astype(float) > 0)


def _fill_unseen(robot: RobotKinematics, q: np.ndarray, unseen: np.ndarray) -> np.ndarray:
    """q (F, nq) with each direction's unseen frames linearly interpolated (unwrapped) from its seen ones."""
    q = q.copy()
    f = np.arange(len(q))
    for v in np.flatnonzero(unseen.any(0) & ~unseen.all(0)):
        qi = robot.q_of_v[v]
        if qi < 0:
            continue
        ok = ~unseen[:, v]
        vals = np.unwrap(q[ok, qi]) if robot.revolute[qi] else q[ok, qi]
        q[~ok, qi] = np.interp(f[~ok], f[ok], vals)
    return robot.clip(q)


def _gauge_directions(x: np.ndarray, jac: np.ndarray, w: np.ndarray, P: np.ndarray | None, per_frame: bool,
                      tol: float = 1e-3) -> np.ndarray:
    """(nv,) directions whose motion of the tracked points a change of view imitates exactly.

    x (F, J, 3) base-frame points, jac (F, J, 3, nv), w (F, J), P (F, 2, 3) cameras or None (3D: a
    similarity). The generators of a view change are a rotation (omega x x), a scale (x) and a
    translation (in the image only its two in-plane components); one change for the whole sequence
    (per_frame False) or one per frame.
    """
    F, J, _, nv = jac.shape
    G = np.concatenate([-_skew(x), x[..., None], np.broadcast_to(np.eye(3), (F, J, 3, 3))], -1)
    if P is not None:
        G = np.concatenate([np.einsum("fic,fjcg->fjig", P, G[..., :4]),
                            np.broadcast_to(np.eye(2), (F, J, 2, 2))], -1)
        jac = np.einsum("fic,fjcv->fjiv", P, jac)
    sw = np.sqrt(w)[..., None, None]
    G, jac = G * sw, jac * sw
    A = G.reshape(F, -1, G.shape[-1]) if per_frame else G.reshape(1, -1, G.shape[-1])
    b = jac.reshape(len(A), -1, nv)
    res = b - A @ (np.linalg.pinv(A) @ b)
    num = np.sqrt((res ** 2).sum((0, 1)))
    den = np.sqrt((b ** 2).sum((0, 1)))
    return num < tol * np.maximum(den, 1e-300)


def _names_of_v(robot: RobotKinematics) -> list[str]:
    m = robot.model
    return [m.names[j] for j in range(1, m.njoints) for _ in range(m.joints[j].nv)]


def _prefer_rest(robot: RobotKinematics, cands: list[dict], key: str, blind: np.ndarray,
                 floor: float = 0.0, tie=None) -> list[dict]:
    """Candidates sorted by their error ``key``; among those the data cannot tell apart (error within
    1.5 times the best plus ``floor``, as a mirror image often fits as well as the truth; or
    ``tie(best, c)``), the nearest the rest pose (mean absolute joint offset over the fitted,
    observable joints) comes first."""
    cands = sorted(cands, key=lambda c: c[key])
    tie = tie or (lambda b, c: c[key] <= 1.5 * b[key] + floor + 1e-12)
    tied = [c for c in cands if tie(cands[0], c)]

    def distance(c):
        seen = ~(blind | c["gauge"])[robot.v_of_q[robot.v_of_q >= 0]]
        d = _wrapped(robot, c["q"] - robot.q_rest)[:, robot.v_of_q >= 0][:, seen]
        return float(np.abs(d).mean()) if d.size else 0.0

    tied.sort(key=distance)
    tied_ids = {id(c) for c in tied}  # identity: `in` would compare the dicts' arrays
    return tied + [c for c in cands if id(c) not in tied_ids]


def _hold(robot: RobotKinematics, q: np.ndarray, blind: np.ndarray, gauge: np.ndarray,
          per_frame: bool, unseen: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Hold blind directions at rest in every frame; gauge directions at rest in frame 0 (shifting the
    whole sequence, which a view change undoes) or, with per-frame views, at their current values.
    Returns (q, free (F, nv))."""
    q = q.copy()
    free = np.ones((len(q), robot.nv), bool)
    for v in np.flatnonzero(blind | gauge):
        qi = robot.q_of_v[v]
        if blind[v]:
            free[:, v] = False
            if qi >= 0:
                q[:, qi] = robot.q_rest[qi]
        elif per_frame:
            free[:, v] = False
        else:
            free[0, v] = False
            if qi >= 0:
                q[:, qi] += robot.q_rest[qi] - q[0, qi]
    if unseen is not None:  # directions no seen point moves in a frame: held there (at their neighbours')
        free &= ~unseen
        q = _fill_unseen(robot, q, unseen & ~(blind | gauge))
    return robot.clip(q), free


def _notes(robot: RobotKinematics, blind: np.ndarray, gauge: np.ndarray, per_frame: bool) -> list[str]:
    names = _names_of_v(robot)
    notes = []
    if blind.any():
        notes.append("not observable, held at rest (no tracked point moves with it): "
                     + ", ".join(names[v] for v in np.flatnonzero(blind)))
    if gauge.any():
        how = ("not observable, absorbed by each frame's camera, held at the 3D fit" if per_frame else
               "observable only relative to the first frame (a turn of the camera looks the same), "
               "held at rest in frame 0")
        notes.append(f"{how}: {', '.join(names[v] for v in np.flatnonzero(gauge))}")
    if blind.any():
        notes.append("to see a joint, track a point that moves with it, off its axis (extra_frames)")
    if gauge.any():
        notes.append("to see the first joint absolutely, track a point fixed to the base, off its axis")
    return notes


# ---------------------------------------------------------------------------------------------------
# the entry point
# ---------------------------------------------------------------------------------------------------
def _looks_down(view: _View) -> float:
    """How much the camera(s) look down on the base plane: minus the z of the forward axis (the
    rotation's third row, image y pointing down), averaged; > 0 from above."""
    return -float(np.mean(view.R[:, 2, 2]))


def _turned_views(robot: RobotKinematics, q: np.ndarray, view: _View, gauge: np.ndarray,
                  turns: tuple[float, ...] = (0.5 * np.pi, np.pi, -0.5 * np.pi)) -> list[_View]:
    """Views that show the motion q (F, nq) as ``view`` shows it turned by ``turns`` (radians) about
    each gauge direction's axis (``gauge`` (nv,): for an arm on a floor, its first joint, whose turn
    the camera's azimuth imitates): starts for the smoothed search with q itself, and the gauge held in
    frame 0, as they are. Each view is fitted to the image of the turned robot.

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


def _most_probable(robot: RobotKinematics, results: list[dict], tracks: np.ndarray, w: np.ndarray, prior,
                   sigma: float, max_iter: int, tol: float, wrong_side: Callable[[dict], bool],
                   reflected: Callable[[dict], dict],
                   rebranch: Callable[[dict, tuple], tuple[np.ndarray, _View]]) -> tuple[dict, bool, int]:
    """The fit of the most probable motion under the smoothness prior, among ``results`` (refined fits,
    preferred first): each distinct fit that the tracks alone nearly tie is smoothed (:func:`_smooth_lm`)
    and scored by the smoothed objective, robust residuals plus the motion prior (``prior``, the sparse
    matrix of :func:`_motion_prior`), with one Huber threshold for all; a direction that no point seen
    in a frame moves is free there (``free_prior``: the prior interpolates it). When the lowest is seen
    from the wrong side (``wrong_side``), its mirror image (``reflected``: a start with ``q``, ``view``,
    ``free_prior``) is smoothed and scored too. Each
    smoothed fit then gets the branch of every frame chosen again (``rebranch``, a Viterbi pass) and is
    smoothed again while that lowers its score. The best is smoothed again from views turned about
    its gauge joint (:func:`_turned_views`). Of the fits within 25 noise variances of the lowest score,
    the one that moves least (:func:`_roughness`) among those seen from the right side wins, else among
    all; it is returned with its smoothed ``out``.

    Why: a motion that fits the tracks a little better frame by frame (a wrong mirror image of a
    nearly symmetric robot, a branch that jumps) may do so only by moving less plausibly, and the
    prior is what says how plausible a motion is. The refinement frame by frame can also leave jumps
    in one mirror image and not in the other: the smooth one, reflected, gives that side a smooth
    start. Returns (fit, whether another distinct fit tied, iterations).
    """
    best_sse = min(r["sse"] for r in results)
    delta = results[0]["delta"]
    scored: list[tuple[float, dict]] = []
    n_iter = 0

    def smoothed(r, q, view):
        nonlocal n_iter
        out = _smooth_lm(robot, robot.continuous(q), tracks, w, view, r["free_prior"], np.ones(6, bool), max_iter,
                         tol, delta, prior)
        n_iter += out[5]
        return _smoothed_objective(prior, out[0], out[2], w, delta), out

    def score(r, q, view):
        objective, out = smoothed(r, q, view)
        for _ in range(2):  # the smoothed motion may still jump branches that a local step cannot undo
            q_b, view_b = rebranch(r, out)
            if np.abs(_wrapped(robot, q_b - out[0])).max() < 0.05:
                break
            objective_b, out_b = smoothed(r, q_b, view_b)
            if objective_b >= (1 - 1e-3) * objective:
                break
            objective, out = objective_b, out_b
        if not known(out[0]):  # else a motion met before, which keeps its place in the order
            scored.append((objective, dict(r, out=out, q=out[0], down=_looks_down(out[1]))))

    def known(q):
        return any(np.abs(_wrapped(robot, q - o["q"])).max() < 0.05 for _, o in scored)

    for r in results:
        near = r["sse"] <= 1.1 * best_sse + 25.0 * sigma ** 2
        if near and not known(r["q"]):
            score(r, r["out"][0], r["out"][1])  # else a poor fit of the tracks, or one already scored
    best, r = min(scored, key=lambda sr: sr[0])
    for view_t in _turned_views(robot, r["q"], r["out"][1], r["gauge"]):
        score(r, r["q"], view_t)
    best, r = min(scored, key=lambda sr: sr[0])
    # a joint seen again after a long gap: the bridges to its other branches that score alike (the
    # acceleration prior charges nothing for a straight ramp), the one that moves least wins
    least = (_roughness(robot, r["q"]), best, r)
    for q_b in _across_long_gaps(robot, r["q"], tracks, w, r["out"][1], r["free"], sigma, _LONG_GAP):
        objective, out = smoothed(r, q_b, r["out"][1])
        moved = _roughness(robot, out[0])
        if objective <= best + 25.0 * sigma ** 2 and moved < least[0]:
            least = (moved, objective, dict(r, out=out, q=out[0], down=_looks_down(out[1])))
    if least[2] is not r:
        scored = [sr for sr in scored if sr[1] is not r] + [least[1:]]
        r = least[2]
    if wrong_side(r):
        start = reflected(r)
        score(start, start["q"], start["view"])
    lowest = min(sr[0] for sr in scored)
    tied = [r for sr, r in scored if sr - lowest <= 25.0 * sigma ** 2]
    return min(tied, key=lambda r: (wrong_side(r), _roughness(robot, r["q"]))), len(tied) > 1, n_iter


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
        from .urdf import from_urdf

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
    speed_decay_s: float | None = None,
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
        every frame on its own.
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
    poses, chain, urdf, tracks, confidence = _inputs(rec_or_poses, urdf, chain, tracks, confidence)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    robot = RobotKinematics(urdf, chain)
    F = len(poses)
    per_frame = camera == "per-frame"
    w3 = np.isfinite(poses).all(-1).astype(float) * (1.0 if confidence is None else confidence)
    if not (w3 > 0).any():
        raise TrackError("no point of any frame is usable (all NaN or zero confidence)")
    Xz = np.nan_to_num(poses)

    # ---- step 1: 3D, both mirror images. Blind directions are known before fitting.
    blind, gauge0 = _structural(robot, w3)
    unseen3 = _unseen(robot, w3)
    _, free_blind = _hold(robot, np.broadcast_to(robot.q_rest, (F, robot.nq)), blind, blind & False, False,
                          unseen3)
    free_sim = np.array([transform != "none"] * 3 + [transform == "similarity"] + [transform != "none"] * 3)
    candidates, n_iter = [], 0
    for sign in ((1.0, -1.0) if mirror and transform == "similarity" else (1.0,)):
        X = sign * Xz
        q, view, n_iter_a = _fit_3d(robot, X, w3, free_blind, transform, max_iter, tol,
                                    gauge0 if transform != "none" else blind & False)
        gauge, free = np.zeros(robot.nv, bool), free_blind
        if transform != "none":
            pos, jac = robot.jacobians(q)
            gauge = _gauge_directions(pos, jac, w3, None, False) & ~blind
            q, free = _hold(robot, q, blind, gauge, False, unseen3)
            view = _align(robot.positions(q), X, w3, transform)  # the hold turned the robot: turn the view back
        q, view, rn, pos, conv, it = _sequence_lm(robot, q, X, w3, view, free, free_sim,
                                                  max_iter if tracks is None or not refine else 10, tol, None)
        n_iter += it + n_iter_a
        candidates.append(dict(sign=sign, q=q, view=view, rms=float(np.sqrt((w3 * rn ** 2).sum() / w3.sum())),
                               conv=conv, gauge=gauge, pos=pos))
    candidates = _prefer_rest(robot, candidates, "rms", blind)
    mirror_tied = len(candidates) > 1 and candidates[1]["rms"] <= 1.5 * candidates[0]["rms"] + 1e-12
    best = candidates[0]
    gauge = best["gauge"]
    timings["fit_3d"] = time.perf_counter() - t0

    # ---- step 2: refine on the tracks; both mirrors unless the 3D fit told them apart clearly
    residual_px = cams = ts2 = None
    smoothed = False  # by the acceleration prior, which also fills the frames where a direction is unseen
    converged = best["conv"]
    if refine and tracks is not None:
        t1 = time.perf_counter()
        w2 = np.isfinite(tracks).all(-1).astype(float) * (1.0 if confidence is None else confidence)
        if (w2 > 0).sum() < 6:
            raise TrackError(f"the tracks have {int((w2 > 0).sum())} usable points; the camera needs at least 6")
        # image-size tolerance for exact data: a thousandth of the tracks' extent (0.8 px at 800 px)
        px_floor = 1e-3 * float(max(np.ptp(tracks[..., 0][w2 > 0]), np.ptp(tracks[..., 1][w2 > 0])))
        unseen2 = _unseen(robot, w2)
        never2 = unseen2 & unseen2.all(0)

        def robust_cost(rn):
            return float((w2 * _huber(rn, delta_used[0])[0]).sum())

        delta_used = [None]

        def refine_2d(c):
            nonlocal n_iter
            P0, _ = _affine_camera(c["pos"], tracks, w2, per_frame)
            pos, jac = robot.jacobians(c["q"])
            g2 = (_gauge_directions(pos, jac, w2, P0, per_frame) | c["gauge"]) & ~blind
            q, free = _hold(robot, c["q"], blind, g2 if per_frame else c["gauge"], per_frame, unseen2)
            # with the smoothness prior, a direction unseen in some frames follows its neighbours there
            # (one never seen stays held: the prior alone would leave its level and trend free)
            free_prior = _hold(robot, c["q"], blind, g2 if per_frame else c["gauge"], per_frame, never2)[1]
            view = c["camera0"] if "camera0" in c else _camera_view(c["pos"], tracks, w2, per_frame)
            # per-frame IK on the tracks with this camera (robust far from the solution), then all together
            q = _sequential_ik(robot, tracks, w2, view, free, q[0], c["gauge"])
            for _ in range(4):  # alternate the closed-form camera(s) with per-frame IK
                view = _camera_view(robot.positions(q), tracks, w2, per_frame)
                q, _, _, _, _, it = _sequence_lm(robot, q, tracks, w2, view, free, np.zeros(6, bool), 10, 1e-8,
                                                 None)
                n_iter += it
            pos = robot.positions(q)
            rn0 = np.linalg.norm(view.apply(pos)[0] - np.nan_to_num(tracks), axis=-1)
            delta = (_robust_scale(rn0, w2, px_floor) if loss_scale_px is None else
                     (float(loss_scale_px) if loss_scale_px > 0 else None))
            delta_used[0] = delta
            out = _sequence_lm(robot, q, tracks, w2, view, free, np.ones(6, bool), max_iter, tol, delta)
            for _ in range(2):  # then the branch of every frame, chosen for the whole sequence
                sig = max(_noise_sigma(out[2], w2), px_floor)
                q_fix, view_fix = _viterbi_reanchored(robot, out[0], tracks, w2, out[1], free, sig, c["gauge"],
                                                      per_frame, blind, unseen2)
                if np.abs(_wrapped(robot, q_fix - out[0])).max() < 0.05:
                    break
                new = _sequence_lm(robot, q_fix, tracks, w2, view_fix, free, np.ones(6, bool), max_iter, tol, delta)
                worst_old = np.nanmax(_rms_per_frame(out[2], w2))
                better = robust_cost(new[2]) <= 0.99 * robust_cost(out[2]) and \
                    np.nanmax(_rms_per_frame(new[2], w2)) <= 1.1 * worst_old + px_floor
                # a tie of the tracks (a wrist whose tracked points lie in one plane, mirrored in depth):
                # the continuous path wins, and of two alike continuous ones the one nearer the rest pose
                tie = robust_cost(new[2]) <= 1.05 * robust_cost(out[2])
                rough_new, rough_old = _roughness(robot, new[0]), _roughness(robot, out[0])
                smoother = rough_new < 0.5 * rough_old and rough_old - rough_new > 1.0  # a jump gone
                nearer = rough_new <= 1.5 * rough_old + 1.0 and \
                    _rest_distance(robot, new[0], new[0][:1], c["gauge"]).mean() < \
                    _rest_distance(robot, out[0], out[0][:1], c["gauge"]).mean() - 0.1
                if not (better or tie and (smoother or nearer)):
                    break  # only a better fit of the tracks, or an equal fit by a smoother path or nearer rest
                out = new
            # free where unseen too: a branch held there could not turn with the rest of its path
            q_rest_branch = _nearest_rest_branch(robot, out[0], free_prior)
            if q_rest_branch is not out[0]:
                out = _sequence_lm(robot, q_rest_branch, tracks, w2, out[1], free, np.ones(6, bool), max_iter, tol,
                                   delta)
            n_iter += out[-1]
            return dict(cost=float(np.sqrt((w2 * out[2] ** 2).sum() / w2.sum())), sse=float((w2 * out[2] ** 2).sum()),
                        n_obs=2 * int((w2 > 0).sum()), out=out, c=c, g2=g2,
                        q=out[0], gauge=g2, down=_looks_down(out[1]), free=free, free_prior=free_prior, delta=delta)

        def seen_from_wrong_side(r):
            return view_from is not None and (r["down"] < -0.02 if view_from == "above" else r["down"] > 0.02)

        # both mirror images: a poor reconstruction may favour the wrong one in 3D
        results = [refine_2d(c) for c in candidates]
        if not per_frame and transform == "similarity" and min(r["cost"] for r in results) > 3 * px_floor:
            # the tracks are fitted poorly from the reconstruction's start: also a camera found from the
            # tracks alone (costly, so only then)
            v2, q2 = _initial_camera(robot, tracks, w2, _hold(robot, candidates[0]["q"], blind, candidates[0]["gauge"],
                                                              False)[1])
            alt = refine_2d(dict(candidates[0], q=q2, pos=robot.positions(q2), camera0=v2))
            if alt["cost"] * 1.5 < min(r["cost"] for r in results):  # clearly better, not a tie
                results.append(alt)
        def tracks_tie(a, b):
            # refined fits: b is as good as a unless its squared residuals exceed a's by more than
            # 25 noise variances (a likelihood ratio test, noise estimated from a's residuals)
            var = max(a["sse"] / max(a["n_obs"], 1), (0.05 * px_floor) ** 2)
            return b["sse"] - a["sse"] <= 25.0 * var

        def order(rs):
            # among the fits the tracks cannot tell apart: seen from the right side first, then the
            # one nearer the rest pose
            best_fit = min(rs, key=lambda r: r["sse"])
            n_tied = sum(tracks_tie(best_fit, r) for r in rs)
            rs = _prefer_rest(robot, rs, "cost", blind, tie=tracks_tie)
            rs[:n_tied] = sorted(rs[:n_tied], key=seen_from_wrong_side)
            return rs, n_tied > 1

        results, mirror_tied = order(results)
        def reflection(r, M):
            # r's motion reflected by M (3 x 3, base frame), fitted in 3D from the refined motion (a far
            # better start than the reconstruction): a candidate to refine on the tracks
            nonlocal n_iter
            X_alt = np.einsum("ij,fkj->fki", M, r["out"][3])
            q_a, view_a, it_a = _fit_3d(robot, X_alt, w3, free_blind, transform, max_iter, tol, gauge0)
            q_a, free_a = _hold(robot, q_a, blind, r["c"]["gauge"], False, unseen3)
            view_a = _align(robot.positions(q_a), X_alt, w3, transform)
            q_a, view_a, rn_a, pos_a, conv_a, it_b = _sequence_lm(robot, q_a, X_alt, w3, view_a, free_a,
                                                                  free_sim, 20, tol, None)
            n_iter += it_a + it_b
            return dict(sign=-r["c"]["sign"], q=q_a, pos=pos_a, gauge=r["c"]["gauge"], conv=conv_a)

        def depth_mirror(r):
            R0 = r["out"][1].R[0] if not per_frame else r["out"][1].R.mean(0)
            return R0.T @ np.diag([1.0, 1.0, -1.0]) @ R0

        def rebranch(r, out):
            sig = max(_noise_sigma(out[2], w2), px_floor)
            return _viterbi_reanchored(robot, out[0], tracks, w2, out[1], r["free"], sig, r["c"]["gauge"], per_frame,
                                       blind, unseen2)

        def reflected_start(r):
            # r's depth mirror image, a start for the smoothed fit (held as the refinement holds)
            c = reflection(r, depth_mirror(r))
            q = _hold(robot, c["q"], blind, c["gauge"], False, unseen2)[0]
            return dict(r, c=c, q=q, free_prior=_hold(robot, q, blind, c["gauge"], False, never2)[1],
                        view=_camera_view(robot.positions(q), tracks, w2, False))

        if transform == "similarity":
            # Two reflections keep every track: the depth mirror (weak perspective), and for a robot
            # built mirror-symmetric (its tracked points in one vertical plane at rest) the mirror about
            # that plane, seen through the mirrored camera. The best motion is tried under both; when a
            # reflection wins (a better fit found from the reflected start), it is reflected in turn,
            # since its own mirror image may be the one seen from the right side.
            reflected: list[dict] = []
            while len(reflected) < 2 and not any(results[0] is r for r in reflected):
                r0 = results[0]
                reflected.append(r0)
                alts = [refine_2d(reflection(r0, M)) for M in (depth_mirror(r0), np.diag([1.0, -1.0, 1.0]))]
                results, mirror_tied = order(results + alts)
        r = results[0]
        sigma = _noise_sigma(r["out"][2], w2)
        if accel_std is not None and robot.euclidean and F >= 3 and not per_frame and sigma > 1e-6:
            # joint accelerations ~ N(0, accel_std^2) against pixel noise sigma: the prior's weight
            mu = sigma ** 2 / (float(accel_std) / float(fps) ** 2) ** 2
            smoothed = True
            decay_frames = np.inf if speed_decay_s is None else speed_decay_s * float(fps)
            r, mirror_tied, it = _most_probable(robot, results, tracks, w2, _motion_prior(unseen2, mu, decay_frames),
                                                max(sigma, px_floor), max_iter, tol, seen_from_wrong_side,
                                                reflected_start, rebranch)
            n_iter += it
        (q, view, rn, pos_base, conv2, _), best, gauge = r["out"], r["c"], r["g2"]
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
    observable = np.ones(robot.nq, bool)
    relative = np.zeros(robot.nq, bool)
    for v in np.flatnonzero(blind | gauge):
        qi = robot.q_of_v[v]
        if qi >= 0:
            observable[qi] = False
            relative[qi] = bool(gauge[v] and not blind[v] and not per_frame)
    notes = _notes(robot, blind, gauge & ~blind, per_frame)
    if residual_px is not None:  # view: the fitted camera(s); its third row is the depth axis
        for parent, turned, frames in _face_on_planes(robot, q, view.R[view.cam_of][:, 2]):
            notes.append(f"the tracked points beyond {parent} lie in one plane that the camera sees within {FACE_ON_DEG:g} "
                         f"degrees of face-on in frames {_frame_ranges(frames)}: there the motion can pass unseen "
                         f"to its mirror image in depth ({', '.join(turned)} differ), so the branch after those "
                         "frames is a guess; track a point off that plane (extra_frames) to settle it")
    msg = "; ".join(notes) if notes else "all joints observable"
    if mirror_tied:
        msg += ("; the motion and its mirror image fit the data equally well (weak perspective): "
                + (f"the one seen from {view_from} the base plane is reported" if refine and tracks is not None
                   and view_from else "the one nearer the rest pose is reported"))
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
    )
