"""The result of a joint-angle fit: :class:`JointFit`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any
import numpy as np

from ..chain import KinematicChain
from .kinematics import RobotKinematics


def joint_flags(fit: Any, attr: str, n: int | None = None) -> np.ndarray:
    """(n,) bool: the fit's per-joint flags ``attr`` (such as ``ambiguous`` or ``relative``), n the
    number of joints (default: ``len(fit.joint_names)``); all False when the fit has none (None or
    empty: a fit saved before they existed). Flags of any other length raise a
    :class:`~chainspace.errors.TrackError` naming the field and both lengths: read one per joint, they
    would mark the wrong joints."""
    from ..errors import TrackError

    n = len(fit.joint_names) if n is None else n
    value = getattr(fit, attr, None)
    flags = np.zeros(0, bool) if value is None else np.asarray(value, dtype=bool).reshape(-1)
    if flags.size == 0:
        return np.zeros(n, bool)
    if flags.size != n:
        raise TrackError(f"the fit's {attr!r} has {flags.size} flags for {n} joints ({', '.join(fit.joint_names)}); "
                         "it was not saved by this fit")
    return flags


def playback_fps(fit: Any, fps: float | None = None) -> float:
    """The frame rate (frames per second) to draw or play a fit's motion at: ``fps`` when given, else the
    one the fit assumed (:attr:`JointFit.fps`), else 30 (a fit saved before it was kept, or none)."""
    own = getattr(fit, "fps", None)
    return float(fps if fps is not None else own if own is not None and np.isfinite(own) and own > 0 else 30.0)


def reprojection_rms(fit: Any) -> float | None:
    """A fit's reprojection error over all frames (px RMS, from ``fit.residual_px``, per frame): None for a
    fit without tracks, NaN where no frame has one."""
    r = getattr(fit, "residual_px", None)
    if r is None:
        return None
    r = np.asarray(r, float)
    return float(np.sqrt(np.nanmean(r ** 2))) if np.isfinite(r).any() else float("nan")


def joint_reasons(fit: Any) -> list[str]:
    """Why each joint of the fit is flagged (one string per joint, "" where it is not; see
    :attr:`JointFit.joint_reasons`). A fit saved before the reasons were kept per joint gives its
    whole message for each flagged joint."""
    n = len(fit.joint_names)
    reasons = list(getattr(fit, "joint_reasons", None) or [])
    if len(reasons) == n:
        return [str(r) for r in reasons]
    if reasons:
        from ..errors import TrackError

        raise TrackError(f"the fit's joint_reasons has {len(reasons)} entries for {n} joints; it was not saved by this fit")
    return [str(fit.message) if a else "" for a in joint_flags(fit, "ambiguous", n)]


@dataclass
class JointFit:
    """Joint angles fitted to a robot's motion.

    q (F, nq) radians / metres in Pinocchio's order (a continuous joint as (cos, sin)); joint_names one
    per degree of freedom (nv: one per moving joint, mimic joints excluded), as are observable (nv,) bool
    (False: held fixed, see the module docstring) and relative (nv,) bool (seen only relative to the
    first frame); :attr:`angles` (F, nv) one angle per joint (radians, metres for prismatic joints); positions (F, J, 3) fitted chain points in the reconstruction's frame (metres when the
    reconstruction is); residual_3d (F,) RMS distance to the reconstructed points; residual_px (F,) RMS
    reprojection error or None; converged (F,) bool; scale, rotation (3, 3), translation (3,) the
    similarity from the robot's base frame to the reconstruction's; cameras (F, 2, 3) and
    translations_2d (F, 2) map the base frame to the image (``u = cameras[f] @ x + translations_2d[f]``;
    with a pinhole camera the weak-perspective camera that linearises it at the robot's depth).
    With a pinhole camera (``fit_joint_angles(..., intrinsics=...)`` or a measured focal):
    ``intrinsics`` (K, undistort), ``camera_pose`` (R, t) with ``x_cam = R x_base + t`` in metres;
    ``focal_px``, ``focal_std_px`` when the focal length was estimated (also when it was not
    measurable and the weak-perspective fit is reported).

    How sure the fit is (fits refined on 2D tracks; :mod:`chainspace.robot.uncertainty`): ``q_std``
    (F, nv) one standard deviation per frame and joint, radians (metres for prismatic joints), from the
    fit's Gauss-Newton covariance scaled by the measured pixel noise ``noise_px`` (px per image
    coordinate); NaN where a joint is held (not observable). ``alternatives``: the other motions that
    fit the tracks as well (a likelihood-ratio test), each ``{"angles": (F, nv), "score": how much
    worse in noise variances, "settled_by": the rule that validly set it aside or None}``.
    ``ambiguous`` (nv,) bool: joints reported, not trusted: an unsettled alternative differs there by
    more than :data:`~chainspace.robot.uncertainty.AMBIGUOUS_DEG` degrees RMS ("tie"), the fit misses a
    tracked point the joint moves, or a base point on average ("poor fit"), or twice its standard
    deviation, plus any such alternative's difference, is more than that ("uncertain",
    :data:`~chainspace.robot.uncertainty.UNCERTAIN_SIGMAS`);
    ``joint_reasons`` (nv,) str: why, per joint ("" where not flagged). ``fps``: the frame rate (frames per
    second) the motion prior assumed, which plots and the viewer play the motion at; ``accel_std``,
    ``jerk_std``: the priors the answer was fitted under (the ones asked for, or wider where the motion
    was faster than they allow: see ``message``).
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
    intrinsics: Any = None  # the pinhole camera used (K, undistort[, project]) or None (weak perspective)
    camera_pose: tuple[np.ndarray, np.ndarray] | None = None  # (R (3, 3), t (3,)): x_cam = R x_base + t, metres
    focal_px: float | None = None  # estimated focal length (image_size given, no intrinsics)
    focal_std_px: float | None = None
    q_std: np.ndarray | None = None  # (F, nv) rad / m; NaN where held
    noise_px: float | None = None  # measured pixel noise (per coordinate) that scales q_std
    alternatives: list[dict] = field(default_factory=list)  # {"angles" (F, nv), "score", "settled_by"}
    ambiguous: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # (nv,)
    joint_reasons: list[str] = field(default_factory=list)  # (nv,) why each ambiguous joint is; "" elsewhere
    fps: float | None = None  # frames per second the motion prior assumed; None in fits saved before it was kept
    accel_std: float | None = None  # the motion priors the answer was fitted under (rad/s^2, rad/s^3); None: none
    jerk_std: float | None = None

    @property
    def n_frames(self) -> int:
        return len(self.q)

    @property
    def angles(self) -> np.ndarray:
        """(F, nv) one coordinate per joint in the order of ``joint_names``: radians (a continuous joint's
        (cos, sin) as an angle, unwrapped over the frames), metres for prismatic joints. Equal to ``q``
        when every joint has one configuration entry."""
        q = np.asarray(self.q, float)
        if q.shape[-1] == len(self.joint_names):
            return q.copy()
        return self.kinematics().angles(q)

    def kinematics(self) -> RobotKinematics:
        """The Pinocchio model used by the fit (rebuilt from ``urdf_path``)."""
        return RobotKinematics(self.urdf_path, self.chain)

    def reprojected(self) -> np.ndarray | None:
        """(F, J, 2) the fitted robot seen by the fitted camera, or None without a camera."""
        if self.positions_base is None:
            return None
        if self.intrinsics is not None and self.camera_pose is not None:
            R, t = self.camera_pose
            y = self.positions_base @ np.asarray(R).T + np.asarray(t)
            if hasattr(self.intrinsics, "project"):
                return self.intrinsics.project(y)  # a PinholeCamera: lens distortion included
            K = np.asarray(self.intrinsics.K, float)
            return (y[..., :2] / y[..., 2:]) @ K[:2, :2].T + K[:2, 2]
        if self.cameras is None:
            return None
        return np.einsum("fij,fkj->fki", self.cameras, self.positions_base) + self.translations_2d[:, None]

    def joint_status(self) -> list[str]:
        """Per joint (``joint_names``): "observable", "relative to frame 0", "not observable" or
        "ambiguous" (an alternative motion that fits as well differs there: see ``alternatives``)."""
        n = len(self.joint_names)
        amb, rel = joint_flags(self, "ambiguous", n), joint_flags(self, "relative", n)
        obs = np.asarray(self.observable, bool).reshape(-1)
        if obs.size != n:  # a fit saved with one flag per q entry
            obs = np.ones(n, bool)
        return ["ambiguous" if a else "observable" if o else "relative to frame 0" if r else "not observable"
                for a, o, r in zip(amb, obs, rel)]

    def summary(self) -> str:
        """Plain text, one line per joint: its status, median standard deviation (degrees, mm for
        prismatic joints) and why it is flagged, then the measured pixel noise, the alternatives and the fit's message."""
        lines = []
        reasons = joint_reasons(self)
        std = None if self.q_std is None else np.asarray(self.q_std, float)
        prismatic = (self.kinematics().prismatic_v if std is not None and self.urdf_path
                     else np.zeros(len(self.joint_names), bool))
        for k, (name, status) in enumerate(zip(self.joint_names, self.joint_status())):
            sd = ""
            if std is not None and np.isfinite(std[:, k]).any():
                unit, scale = ("mm", 1000.0) if prismatic[k] else ("deg", np.degrees(1.0))
                sd = f", std {scale * float(np.nanmedian(std[:, k])):.2f} {unit} (median over frames)"
            lines.append(f"{name}: {status}{sd}" + (f" ({reasons[k]})" if reasons[k] and reasons[k] != self.message else ""))
        if self.noise_px is not None and np.isfinite(self.noise_px):
            lines.append(f"measured pixel noise: {self.noise_px:.2f} px")
        if self.alternatives:
            lines.append(f"{len(self.alternatives)} other motion(s) fit the tracks as well: "
                         + ", ".join(f"{a['score']:.1f} noise variances worse"
                                     + (f" (set aside by the {a['settled_by']} rule)" if a.get("settled_by") else "")
                                     for a in self.alternatives))
        lines.append(self.message)
        return "\n".join(lines)

    def __repr__(self) -> str:
        obs = int(self.observable.sum())
        px = "" if self.residual_px is None else f", reprojection {np.nanmean(self.residual_px):.3g} px"
        return (f"JointFit({self.n_frames} frames, {len(self.joint_names)} q entries ({obs} observable){px}, "
                f"converged {int(self.converged.sum())}/{self.n_frames}: {self.message})")
