"""Which joints the tracks can see: joints no tracked point moves with, joints a camera motion
imitates (gauge directions), directions unseen in some frames, and the notes that say so.
"""

from __future__ import annotations

import numpy as np

from .kinematics import RobotKinematics
from .views import _skew


def _structural(robot: RobotKinematics, w: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """What the tracked points (those with weight somewhere in w (F, J)) can see, from the structure
    alone: at a few random configurations, the (nv,) directions that move no tracked point (blind) and
    those a change of the sequence's similarity imitates (gauge)."""
    qs = _probe_q(robot, np.random.default_rng(seed))
    pos, jac = robot.jacobians(qs)
    seen = (w > 0).any(0)
    ext = max(np.linalg.norm(pos[:, seen] - pos[:, seen].mean(1, keepdims=True), axis=-1).max(), 1e-9)
    blind = np.linalg.norm(jac[:, seen], axis=2).max(axis=(0, 1)) < 1e-9 * ext
    gauge = _gauge_directions(pos[:, seen], jac[:, seen], np.ones((3, seen.sum())), None, False) & ~blind
    return blind, gauge


def _probe_q(robot: RobotKinematics, rng: np.random.Generator) -> np.ndarray:
    """(3, nq) configurations drawn within the joint limits (a turn either way where there are none)."""
    lo = np.where(robot.limited_v, robot.lower_v, -np.pi)
    hi = np.where(robot.limited_v, robot.upper_v, np.pi)
    return robot.clip(robot.from_angles(rng.uniform(lo, hi, (3, robot.nv))))


def _weights(x: np.ndarray, confidence) -> np.ndarray:
    """(F, J) weights of observed points x (F, J, D): their confidence (1 where None) where finite, else 0."""
    return np.isfinite(x).all(-1).astype(float) * (1.0 if confidence is None else confidence)


def _moves(robot: RobotKinematics, seed: int = 0) -> np.ndarray:
    """(J, nv) which directions move which of the chain's points, from the structure alone (at a few
    random configurations: a point on a joint's axis in one pose is not taken for one it never leaves)."""
    qs = _probe_q(robot, np.random.default_rng(seed))
    pos, jac = robot.jacobians(qs)
    ext = max(np.linalg.norm(pos - pos.mean(1, keepdims=True), axis=-1).max(), 1e-9)
    return np.linalg.norm(jac, axis=2).max(0) > 1e-9 * ext


def _point_movers(robot: RobotKinematics, q: np.ndarray) -> np.ndarray:
    """(J, nv) which directions move which of the chain's points in the motion q (F, nq): read from the
    Jacobians of five of its frames (all of them when fewer), where :func:`_moves` reads the structure."""
    frames = np.unique(np.linspace(0, len(q) - 1, min(len(q), 5)).round().astype(int))
    return np.linalg.norm(robot.jacobians(q[frames])[1], axis=2).max(0) > 1e-9


def _unseen(robot: RobotKinematics, w: np.ndarray, seed: int = 0) -> np.ndarray:
    """(F, nv) directions that move no point seen in that frame (w (F, J) > 0): the data say nothing
    about them there, so they are held and later interpolated from the neighbouring frames."""
    return ~((w > 0).astype(float) @ _moves(robot, seed).astype(float) > 0)


def _fill_unseen(robot: RobotKinematics, q: np.ndarray, unseen: np.ndarray) -> np.ndarray:
    """q (F, nq) with each direction's unseen frames linearly interpolated (unwrapped) from its seen ones."""
    a = robot.angles(q)  # (F, nv): a continuous joint's (cos, sin) as an angle
    f = np.arange(len(q))
    todo = np.flatnonzero(unseen.any(0) & ~unseen.all(0))
    if not len(todo):
        return robot.clip(q.copy())
    for v in todo:
        ok = ~unseen[:, v]
        vals = np.unwrap(a[ok, v]) if robot.turns_v[v] else a[ok, v]
        a[~ok, v] = np.interp(f[~ok], f[ok], vals)
    out = q.copy()
    changed = robot.q_mask(np.isin(np.arange(robot.nv), todo))
    out[:, changed] = robot.from_angles(a)[:, changed]
    return robot.clip(out)


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
    return list(robot.dof_names)


def _hold(robot: RobotKinematics, q: np.ndarray, blind: np.ndarray, gauge: np.ndarray,
          per_frame: bool, unseen: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Hold blind directions at rest in every frame; gauge directions at rest in frame 0 (shifting the
    whole sequence, which a view change undoes) or, with per-frame views, at their current values.
    Returns (q, free (F, nv))."""
    q = q.copy()
    free = np.ones((len(q), robot.nv), bool)
    free[:, blind] = False
    held = robot.q_mask(blind)
    q[:, held] = robot.q_rest[held]
    shift = gauge & ~blind
    if per_frame:
        free[:, shift] = False
    elif shift.any():  # the whole path turned so that the gauge directions sit at rest in frame 0
        free[0, shift] = False
        a = robot.angles(q)
        a[:, shift] += robot.angles(robot.q_rest)[shift] - a[0, shift]
        moved = robot.q_mask(shift)
        q[:, moved] = robot.from_angles(a)[:, moved]
    if unseen is not None:  # directions no seen point moves in a frame: held there (at their neighbours')
        free &= ~unseen
        q = _fill_unseen(robot, q, unseen & ~(blind | gauge))
    return robot.clip(q), free


def _hold_with_prior(robot: RobotKinematics, q: np.ndarray, blind: np.ndarray, gauge: np.ndarray, per_frame: bool,
                     unseen: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_hold` with the directions ``unseen`` (F, nv) in each frame: (q, free, free_prior), where
    ``free_prior`` are the free directions under the motion prior: there a direction unseen in some frames
    follows its neighbours, and only one never seen stays held (the prior alone would leave its level and
    trend free)."""
    q, free = _hold(robot, q, blind, gauge, per_frame, unseen)
    return q, free, _hold(robot, q, blind, gauge, per_frame, unseen & unseen.all(0))[1]


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
