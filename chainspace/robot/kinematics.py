"""The robot's Pinocchio model seen as the chain's tracked points: positions, Jacobians, joint-space
steps and distances (angles wrapped on continuous joints, limits kept by projection).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..chain import KinematicChain
from ..errors import DescriptionError, DescriptionNotFoundError


class Placed(NamedTuple):
    """Configurations' kinematics (:meth:`RobotKinematics.placed`): the chain's points (F, J, 3), metres,
    and the joints' world rotations R (njoints, F, 3, 3) and origins p (njoints, F, 3); ``spatial``
    (F, 6, columns that move a point, :attr:`RobotKinematics._cols`): Pinocchio's world joint Jacobian where
    the kinematics looped over Pinocchio, else None (made from R and p when asked)."""

    pos: np.ndarray
    R: np.ndarray
    p: np.ndarray
    spatial: np.ndarray | None


class RobotKinematics:
    """The Pinocchio model of a URDF with one frame per point of a chain, in the chain's order.

    ``positions(q)`` and ``jacobians(q)`` are vectorised over frames (q is (F, nq)): for chains of 1-dof
    joints all frames in one batched pass (:class:`_BatchedKinematics`, read off the Pinocchio model and
    checked against it), otherwise a loop over Pinocchio. Points named in ``chain.metadata["extra_frames"]``
    ({name: (parent_link, [x, y, z])}) are added as operational frames.
    """

    def __init__(self, urdf: str | Path, chain: KinematicChain) -> None:
        import pinocchio as pin

        self.pin = pin
        path = Path(urdf)
        if not path.is_file():
            raise DescriptionNotFoundError(f"URDF file {path} does not exist")
        from ..io.urdf import build_model

        self.model = build_model(path)
        _check_supported_joints(self.model, path)
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
        self._init_spaces()
        self.joint_names = self.dof_names  # one per degree of freedom (nv): what fits report
        # Each point as its joint's placement applies it: the parent joint, the point in its frame
        # (homogeneous), and the velocity directions that move it (J, nv): its supporting joints.
        self._parent_joint = np.array([m.frames[fid].parentJoint for fid in self.frame_ids], int)
        self._in_parent = np.array([np.append(m.frames[fid].placement.translation, 1.0) for fid in self.frame_ids])
        # Mimic joints (Pinocchio >= 3.4) have columns of their own in the Jacobian (nvExtended), already
        # scaled by the mimic's multiplier; _fold (nvExtended, nv) adds each onto its leader's velocity.
        nvx = int(getattr(m, "nvExtended", self.nv))
        self._fold = np.zeros((nvx, self.nv))
        for j in range(1, m.njoints):
            jm = m.joints[j]
            x0 = int(getattr(jm, "idx_vExtended", jm.idx_v))
            if jm.shortname() == "JointModelMimic":
                self._fold[x0, jm.idx_v] = 1.0
            else:
                self._fold[x0:x0 + jm.nv, jm.idx_v:jm.idx_v + jm.nv] += np.eye(jm.nv)
        self._carried_by = np.zeros((len(self.frame_ids), nvx), bool)
        for k, parent in enumerate(self._parent_joint):
            for j in m.supports[int(parent)][1:]:
                jm = m.joints[j]
                x0 = int(getattr(jm, "idx_vExtended", jm.idx_v))
                self._carried_by[k, x0:x0 + int(getattr(jm, "nvExtended", jm.nv))] = True
        # Only the joints that carry a tracked point are placed and differentiated: a gripper's fingers
        # beyond the last tracked point move none (the Panda's two: 10-19 % of its kinematics' time a call)
        self._cols = np.flatnonzero(self._carried_by.any(0))  # the extended velocity columns that move a point
        self._carried_by, self._fold = self._carried_by[:, self._cols], self._fold[self._cols]
        self._mimic = not np.array_equal(self._fold, np.eye(self.nv))  # a mimic, or a column that moves nothing
        self._batch = _BatchedKinematics.of(self)
        # Where solvers start from "the rest pose": the rest pose with every revolute joint turned a
        # little, because rest poses are often singular (a stretched wrist, an upright arm), where the
        # gradient cannot tell a joint's sign.
        a_rest = self.angles(self.q_rest)
        up = a_rest + 0.3
        seed = np.where(self.limited_v & (up > self.upper_v), a_rest - 0.3, up)
        a_seed = np.where(self.turns_v, seed, a_rest)
        self.q_seed = self.clip(self.from_angles(a_seed))
        self.q_seed_other = self.clip(self.from_angles(2 * a_rest - a_seed))  # turned the other way

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

    def _init_spaces(self) -> None:
        """How q (nq, Pinocchio's configuration) and velocities / angles (nv) correspond, per joint.

        A revolute or prismatic joint has one entry in each; a continuous joint two in q (cos, sin) and
        one angle; a mimic joint (Pinocchio >= 3.4) none: its leader drives it. ``_qv`` (nq, nv) marks
        the entries of each joint in both spaces: :meth:`q_mask` and :meth:`v_mask` map masks through it.
        """
        m, nq, nv = self.model, self.nq, self.nv
        self._qv = np.zeros((nq, nv), bool)
        self.dof_names: list[str] = []
        self.turns_v = np.zeros(nv, bool)  # angles that wrap: revolute and continuous joints
        self.prismatic_v = np.zeros(nv, bool)
        self.continuous_v = np.zeros(nv, bool)
        self.limited_v = np.zeros(nv, bool)
        self.lower_v, self.upper_v = np.full(nv, -np.inf), np.full(nv, np.inf)
        for j in range(1, m.njoints):
            jm = m.joints[j]
            if jm.nv == 0:  # a mimic joint
                continue
            self._qv[jm.idx_q:jm.idx_q + jm.nq, jm.idx_v:jm.idx_v + jm.nv] = True
            self.dof_names += [m.names[j]] if jm.nv == 1 else [f"{m.names[j]}[{k}]" for k in range(jm.nv)]
            if jm.nq == 1 and jm.nv == 1:
                v, i = jm.idx_v, jm.idx_q
                self.turns_v[v] = self.revolute[i]
                self.prismatic_v[v] = not self.revolute[i]
                self.limited_v[v] = self.limited[i]
                self.lower_v[v], self.upper_v[v] = self.lower[i], self.upper[i]
            elif jm.nq == 2 and jm.nv == 1:
                self.turns_v[jm.idx_v] = self.continuous_v[jm.idx_v] = True

    def q_mask(self, v_mask: np.ndarray) -> np.ndarray:
        """(..., nq) the configuration entries of the joints whose directions ``v_mask`` (..., nv) marks
        (both entries (cos, sin) of a continuous joint)."""
        v_mask = np.asarray(v_mask, bool)
        return (v_mask.astype(float) @ self._qv.T.astype(float)) > 0

    def v_mask(self, q_mask: np.ndarray) -> np.ndarray:
        """(..., nv) the directions of the joints any of whose configuration entries ``q_mask`` (..., nq)
        marks."""
        q_mask = np.asarray(q_mask, bool)
        return (q_mask.astype(float) @ self._qv.astype(float)) > 0

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

    def wrap_angles(self, d: np.ndarray) -> np.ndarray:
        """Differences of per-dof coordinates d (..., nv) (:meth:`angles`) with the angles that wrap
        (``turns_v``: revolute and continuous joints) moved into [-pi, pi); prismatic ones as given."""
        return np.where(self.turns_v, (d + np.pi) % (2 * np.pi) - np.pi, d)

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
                a = np.arctan2(q[..., jm.idx_q + 1], q[..., jm.idx_q])
                out[..., jm.idx_v] = np.unwrap(a, axis=0) if a.ndim else a
            else:
                for f in np.ndindex(q.shape[:-1]):
                    d = self.pin.difference(m, self.q_rest, q[f])
                    out[f + (slice(jm.idx_v, jm.idx_v + jm.nv),)] = d[jm.idx_v:jm.idx_v + jm.nv]
        return out

    def from_angles(self, a: np.ndarray) -> np.ndarray:
        """Configurations (..., nq) of per-dof coordinates a (..., nv), the inverse of :meth:`angles`:
        a continuous joint's angle as (cos, sin)."""
        a = np.asarray(a, float)
        if self.euclidean:
            return a.copy()
        out = np.broadcast_to(self.q_rest, a.shape[:-1] + (self.nq,)).copy()
        m = self.model
        for j in range(1, m.njoints):
            jm = m.joints[j]
            if jm.nv == 0:
                continue
            if jm.nq == jm.nv:
                out[..., jm.idx_q:jm.idx_q + jm.nq] = a[..., jm.idx_v:jm.idx_v + jm.nv]
            elif jm.nq == 2 and jm.nv == 1:
                out[..., jm.idx_q], out[..., jm.idx_q + 1] = np.cos(a[..., jm.idx_v]), np.sin(a[..., jm.idx_v])
            else:  # not reached: RobotKinematics refuses other multi-dof joints
                raise DescriptionError(f"{self.urdf_path}: joint {m.names[j]!r} has no angle coordinates")
        return out

    # ------------------------------------------------------------------ kinematics
    def positions(self, q: np.ndarray) -> np.ndarray:
        """World positions (F, J, 3) of the chain's points for configurations q (F, nq), metres."""
        pin, m, d = self.pin, self.model, self.data
        q = np.atleast_2d(q)
        if self._batch is not None:
            return self._points(*self._batch.placements(q))
        placements = np.empty((m.njoints, len(q), 4, 4))
        for f, qf in enumerate(q):
            pin.forwardKinematics(m, d, qf)
            placements[:, f] = [M.homogeneous for M in d.oMi.tolist()]
        return self._points(placements[..., :3, :3], placements[..., :3, 3])

    def _points(self, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The chain's points (F, J, 3) from the joints' world rotations (njoints, F, 3, 3) and origins
        (njoints, F, 3): one product for all points and frames, where reading each point's placement
        from Pinocchio takes a call."""
        k = self._parent_joint
        return np.einsum("jfab,jb->fja", R[k], self._in_parent[:, :3]) + p[k].swapaxes(0, 1)

    def jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (F, J, 3) and translational frame Jacobians (F, J, 3, nv) in world axes (C-ordered)."""
        placed = self.placed(q)
        return placed.pos, np.ascontiguousarray(self.jacobians_of(placed))

    def placed(self, q: np.ndarray) -> Placed:
        """The kinematics of configurations q (F, nq): the positions (F, J, 3) and what
        :meth:`jacobians_of` needs to give any frames' Jacobians later without redoing them.

        Why: a solver needs Jacobians only at the steps it accepts and goes on from, while it evaluates
        every trial step; about a third of a branch search's trials are rejected or end their search."""
        pin, m, d = self.pin, self.model, self.data
        q = np.atleast_2d(q)
        spatial = None
        if self._batch is not None:
            R, p = self._batch.placements(q)
        else:
            placements = np.empty((m.njoints, len(q), 4, 4))
            spatial = np.empty((len(q), 6, len(self._cols)))
            for f, qf in enumerate(q):
                pin.computeJointJacobians(m, d, qf)
                spatial[f] = d.J[:, self._cols]
                placements[:, f] = [M.homogeneous for M in d.oMi.tolist()]
            R, p = placements[..., :3, :3], placements[..., :3, 3]
        return Placed(self._points(R, p), R, p, spatial)

    def jacobians_of(self, placed: Placed, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Translational frame Jacobians (len(rows), J, 3, nv), world axes, of the frames ``rows`` of
        configurations already :meth:`placed` (the numbers of :meth:`jacobians` of those rows), as a
        view with the frames innermost in memory: a caller whose products depend on the layout (BLAS
        or not) makes it C-ordered first."""
        R, p = placed.R[:, rows], placed.p[:, rows]
        spatial = self._batch.world_jacobian(R, p) if placed.spatial is None else placed.spatial[rows]
        # What pin.getFrameJacobian(LOCAL_WORLD_ALIGNED) returns: the world Jacobian's twist moved to each
        # point, on the joints that carry it; for all points and frames at once. One Pinocchio call per
        # point and frame cost more than the kinematics themselves.
        lin, ang = np.moveaxis(spatial, 0, -1)[:3], np.moveaxis(spatial, 0, -1)[3:]  # (3, nv ext, F)
        x = np.ascontiguousarray(np.moveaxis(placed.pos[rows], 0, -1).swapaxes(0, 1))  # (3, J, F)
        # lin + ang x pos, by components written in place, frames last: numpy's loops then run over
        # all frames at once (frames first, they ran over rows of nv and cost more than the kinematics)
        jac = np.empty((3, x.shape[1], spatial.shape[2], x.shape[2]))  # (3, J, nv ext, F)
        tmp = np.empty(jac.shape[1:])
        for i, k, l in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
            np.multiply(ang[k], x[l][:, None], out=jac[i])
            jac[i] -= np.multiply(ang[l], x[k][:, None], out=tmp)
        jac += lin[:, None]
        jac *= self._carried_by[:, :, None]
        jac = jac.transpose(3, 1, 0, 2)  # (F, J, 3, nv ext), not C-ordered
        return np.ascontiguousarray(jac) @ self._fold if self._mimic else jac

    def reach(self) -> float:
        """Largest distance of a chain point from the root over the rest pose and the limits' middle, m."""
        qs = [self.q_rest, self.clip(np.where(self.limited, 0.5 * (self.lower + self.upper), self.q_rest))]
        p = self.positions(np.array(qs))
        return float(np.linalg.norm(p - p[:, :1], axis=-1).max())


class _BatchedKinematics:
    """Pinocchio's forward kinematics and world joint Jacobian (``computeJointJacobians``: ``oMi`` and
    ``J``) for many configurations at once, in numpy, for chains of 1-dof joints (revolute, continuous,
    prismatic, and mimics of them).

    Why: the fit evaluates thousands of configurations per solver iteration (every frame times every
    start), and a Python loop calling Pinocchio once per configuration cost more than all the
    solver's algebra. Here a loop over the joints does all configurations in one batched product.
    The model's own data decides everything: joint placements, and each joint's axis in its own frame
    read off Pinocchio's Jacobian at the neutral configuration; :meth:`of` returns None for a model
    it does not cover (the callers then loop over Pinocchio).
    """

    _KNOWN = ("JointModelR", "JointModelP", "JointModelMimic")

    def __init__(self, parents, placements, kind, axis, idx_q, col, scaling, offset, nvx):
        self.parents, self.M, self.kind, self.axis = parents, placements, kind, axis
        self.idx_q, self.col, self.scaling, self.offset, self.nvx = idx_q, col, scaling, offset, nvx
        # each axis's cross-product matrix K and K^2 (Rodrigues), made once rather than at every call
        self.K = np.array([[[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]] for a in axis])
        self.KK = self.K @ self.K
        self.joints = list(range(1, len(parents)))  # the joints placed (:meth:`of` keeps those that move a point)
        self.unplaced = []
        self.column_of, self.n_columns = col, nvx  # each joint's column in world_jacobian's J, and their number

    @classmethod
    def of(cls, robot: RobotKinematics) -> "_BatchedKinematics | None":
        pin, m = robot.pin, robot.model
        d = m.createData()
        q0 = pin.neutral(m)
        pin.computeJointJacobians(m, d, q0)
        n = m.njoints
        kind, axis = ["fixed"] * n, np.zeros((n, 3))
        idx_q, col = np.zeros(n, int), np.zeros(n, int)
        scaling, offset = np.ones(n), np.zeros(n)
        for j in range(1, n):
            jm = m.joints[j]
            name = jm.shortname()
            if not name.startswith(cls._KNOWN):
                return None
            col[j] = int(getattr(jm, "idx_vExtended", jm.idx_v))
            idx_q[j] = jm.idx_q
            nq = jm.nq
            if name == "JointModelMimic":
                e = jm.extract()
                scaling[j], offset[j] = float(e.scaling), float(e.offset)
                if scaling[j] == 0.0 or robot.continuous_v[jm.idx_v]:
                    return None  # a mimic of a continuous joint: left to Pinocchio
                nq = 1
            elif jm.nv != 1 or nq not in (1, 2):
                return None
            twist = np.array(d.J[:, col[j]]) / scaling[j]
            Rj = d.oMi[j].rotation
            if np.linalg.norm(twist[3:]) > 1e-9:
                kind[j], axis[j] = ("continuous" if nq == 2 else "revolute"), Rj.T @ twist[3:]
            else:
                kind[j], axis[j] = "prismatic", Rj.T @ twist[:3]
        out = cls(np.array(m.parents), np.array([M.homogeneous for M in m.jointPlacements]), kind, axis, idx_q,
                  col, scaling, offset, int(getattr(m, "nvExtended", m.nv)))
        qr = np.array(robot.q_rest)
        pin.forwardKinematics(m, d, qr)
        R, p = out.placements(qr[None])
        ref = np.array([M.homogeneous for M in d.oMi.tolist()])
        if not (np.allclose(R[:, 0], ref[:, :3, :3], atol=1e-9) and np.allclose(p[:, 0], ref[:, :3, 3], atol=1e-9)):
            return None  # a joint this class reads differently from Pinocchio: keep Pinocchio
        # from here on only the joints that carry a tracked point (parents before children, as Pinocchio
        # numbers them), each Jacobian column at its place among the robot's columns that move a point
        out.joints = sorted({j for k in robot._parent_joint for j in m.supports[int(k)][1:]})
        out.unplaced = sorted(set(range(1, n)) - set(out.joints))
        out.column_of = np.full(n, -1)
        out.column_of[out.joints] = np.searchsorted(robot._cols, col[out.joints])
        out.n_columns = len(robot._cols)
        return out

    def placements(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (njoints, F, 3, 3) and origins (njoints, F, 3) of the joints (Pinocchio's
        ``oMi``) for q (F, nq). Joint-major: each joint's stack is one contiguous block, which the
        products over all frames read and write without copies."""
        F, n = len(q), len(self.parents)
        R, p = np.empty((n, F, 3, 3)), np.empty((n, F, 3))
        R[0], p[0] = np.eye(3), 0.0
        R[self.unplaced], p[self.unplaced] = np.nan, np.nan  # joints that move no tracked point (:meth:`of`)
        for j in self.joints:
            Rp, pp = R[self.parents[j]], p[self.parents[j]]
            # the joint's frame at zero motion, then its motion (Rodrigues about its axis, or a slide
            # along it): products with constant 3x3 matrices, as one matrix product over all frames
            A = _right(Rp, self.M[j, :3, :3])
            p[j] = pp + _right(Rp, self.M[j, :3, 3])
            if self.kind[j] == "prismatic":
                R[j] = A
                p[j] += (self.scaling[j] * q[:, self.idx_q[j]] + self.offset[j])[:, None] * _right(A, self.axis[j])
                continue
            if self.kind[j] == "fixed":
                R[j] = A
                continue
            if self.kind[j] == "continuous":
                c, s = q[:, self.idx_q[j]], q[:, self.idx_q[j] + 1]
            else:
                th = self.scaling[j] * q[:, self.idx_q[j]] + self.offset[j]
                c, s = np.cos(th), np.sin(th)
            # two products, not one with [K | K^2]: the halves of that would be strided, and numpy's
            # elementwise loops over rows of 3 cost more than the second product
            R[j] = A + s[:, None, None] * _right(A, self.K[j]) + (1 - c)[:, None, None] * _right(A, self.KK[j])
        return R, p

    def world_jacobian(self, R: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Pinocchio's world joint Jacobian ``J`` (F, 6, columns) from :meth:`placements`, the columns of the
        joints placed: per joint, the linear velocity of the point at the world origin and the angular
        velocity, as ``computeJointJacobians`` gives it."""
        F = R.shape[1]
        J = np.zeros((6, self.n_columns, F))  # frames innermost: each entry's row of frames is contiguous
        for j in self.joints:
            if self.kind[j] == "fixed":
                continue
            w = _right(self.scaling[j] * R[j], self.axis[j]).T  # (3, F) axis in world axes
            if self.kind[j] == "prismatic":
                J[:3, self.column_of[j]] = w
            else:
                o, c = p[j].T, self.column_of[j]
                J[0, c] = o[1] * w[2] - o[2] * w[1]
                J[1, c] = o[2] * w[0] - o[0] * w[2]
                J[2, c] = o[0] * w[1] - o[1] * w[0]
                J[3:, c] = w
        return J.transpose(2, 0, 1)


def _right(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """A @ B for a stack A (F, 3, 3) and one B (3, 3) or (3,), as one (3F, 3) x (3, 3) (or x (3,)) product:
    numpy's stacked matmul makes one BLAS call per matrix of the stack, which cost more than the
    products for the thousands of configurations of a branch search (the same sums, the same bits)."""
    return (A.reshape(-1, 3) @ B).reshape(A.shape[:-1] + B.shape[1:])


def check_fittable(urdf: str | Path) -> None:
    """Raise :class:`DescriptionError` when the URDF has a joint the fit does not support (a floating
    base): before a command line spends a reconstruction on it, whose own error would name a symptom
    (an untracked world link) rather than the cause."""
    from ..io.urdf import build_model

    _check_supported_joints(build_model(Path(urdf)), urdf)


def _check_supported_joints(model, path) -> None:
    """Joint fits know revolute, continuous, prismatic, fixed and mimic joints; say which joint is not."""
    kinds = {"JointModelFreeFlyer": "floating (free-flyer, 6 degrees of freedom)",
             "JointModelPlanar": "planar (3 degrees of freedom)", "JointModelSpherical": "spherical"}
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.nv > 1 or jm.nq > 2:
            what = kinds.get(jm.shortname(), f"{jm.shortname()} ({jm.nv} degrees of freedom)")
            raise DescriptionError(
                f"{path}: joint {model.names[j]!r} is {what}: a floating-base robot (or a joint of more "
                "than one degree of freedom) is not supported by the joint-angle fit and robot synthesis, "
                "which need a fixed base and 1-dof joints (revolute, continuous, prismatic; fixed and "
                "mimic joints too); fix the base in the URDF (make that joint fixed) to fit the arm on it")


def _held_q(robot: RobotKinematics, free: np.ndarray) -> np.ndarray:
    """(..., nq) entries of q held where free (..., nv) holds their direction."""
    return robot.q_mask(~np.asarray(free, bool))


def _random_q(robot: RobotKinematics, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, nq) configurations drawn uniformly within the joint limits (a turn either way where none)."""
    lo = np.where(robot.limited_v, np.maximum(robot.lower_v, -np.pi), -np.pi)
    hi = np.where(robot.limited_v, np.minimum(robot.upper_v, np.pi), np.pi)
    return robot.clip(robot.from_angles(rng.uniform(lo, hi, (n, robot.nv))))


def _seeded(robot: RobotKinematics, q: np.ndarray, free: np.ndarray, other_side: bool = False) -> np.ndarray:
    """Start configurations (F, nq): the solver seed near the rest pose (or the one turned the other
    way) where a direction is free, the current q where it is held."""
    return np.where(_held_q(robot, free), q, robot.q_seed_other if other_side else robot.q_seed)


def _wrapped(robot: RobotKinematics, dq: np.ndarray) -> np.ndarray:
    """Differences of configurations with revolute joints wrapped into [-pi, pi)."""
    return np.where(robot.revolute, (dq + np.pi) % (2 * np.pi) - np.pi, dq)


def _relative_difference(robot: RobotKinematics, a: np.ndarray, b: np.ndarray,
                         relative: np.ndarray | None) -> np.ndarray:
    """(F, nv) per-dof coordinates a minus b (:meth:`RobotKinematics.angles`), turning joints wrapped; the
    joints ``relative`` (nv,), seen only relative to frame 0, as their change since frame 0 (one offset in
    every frame is a turn of the camera)."""
    d = a - b
    if relative is not None:
        d = d - np.where(relative, d[:1], 0.0)
    return robot.wrap_angles(d)


def _roughness(robot: RobotKinematics, q: np.ndarray) -> float:
    """Sum of squared joint steps between frames (wrapped), rad^2: large where a path jumps branches."""
    return float((_wrapped(robot, np.diff(q, axis=0)) ** 2).sum())


def _gauge_q(robot: RobotKinematics, gauge_v: np.ndarray) -> np.ndarray:
    """(nq,) mask of the q entries driven by the velocity directions gauge_v (nv,)."""
    return robot.q_mask(gauge_v)


def _rest_distance(robot: RobotKinematics, q: np.ndarray, q_prev: np.ndarray, gauge: np.ndarray) -> np.ndarray:
    """Summed absolute joint offsets (wrapped) of q (N, nq) from the rest pose; gauge joints (whose
    absolute value the view absorbs) count from q_prev instead."""
    ref = np.where(_gauge_q(robot, gauge), q_prev, robot.q_rest)
    return np.abs(_wrapped(robot, q - ref)).sum(-1)
