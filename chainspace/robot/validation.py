"""Validation of a robot fit against known kinematics: joint errors, reprojection, bone lengths.

:func:`validate` compares a :class:`~chainspace.robot.fit.JointFit` with the true joint angles when they are
known (a synthetic check, a robot controller's log) and, always, with the robot's own description:
the bone lengths of the reconstruction against the URDF's, and the reprojection error of the fitted
robot. The report passes or fails against thresholds the user sets.

Angles are compared wrapped into [-180, 180) degrees for revolute joints (q and q + 360 degrees are one
pose). Joints the fit marks as seen only relative to the first frame are compared after removing
their mean offset; unobservable joints are listed but not judged. Joints the fit marks ambiguous
(another motion fits the tracks as well and differs there, ``fit.alternatives``) are listed with
their error but not judged: the fit said it does not know. With the fit's standard deviations
(``fit.q_std``) each row also gives the median reported standard deviation and, with a truth, the
share of frames whose error lies within one of them (about 68 % when the deviations are honest).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import DescriptionError, TrackError
from .observability import _weights
from .result import joint_flags, joint_reasons, reprojection_rms
from .uncertainty import CAMERA_MISFIT_RATIO, camera_misfit, track_jitter

__all__ = ["ValidationReport", "validate", "DEFAULT_THRESHOLDS", "BONES_NOTE"]

DEFAULT_THRESHOLDS: dict[str, float] = {
    "joint_rms_deg": 1.0,  # per observable joint, RMS over frames
    "error_3d_pct_reach": 1.0,  # mean 3D point error of the fitted robot, % of reach
    "reprojection_rms_px": float("inf"),  # not judged unless set
    "bone_error_pct": float("inf"),  # reconstructed vs URDF bone lengths, not judged unless set
    # without a truth: the typical tracked point's residual over what the tracks' jitter allows a right
    # model (uncertainty.camera_misfit), by the fit's own rule for a camera that does not explain them
    "tracks_misfit": CAMERA_MISFIT_RATIO,
}


# Below this share of true values within one reported standard deviation (68 % if honest; the 50-trial
# benchmarks give 70-74 %), the report says the deviations understate the errors
STD_HONEST_PCT = 40.0

# Printed above the bone table and stored in the JSON: the two kinds of length are not the same thing.
BONES_NOTE = (
    "Bone lengths: the fitted robot's come from its URDF (metres; the fit moves the URDF's joints, so they "
    "are exact by construction). The reconstruction's come from one camera, which fixes no scale: they "
    "are shown as shares of the chain's total length, beside the URDF's shares. A difference there means "
    "the reconstruction's proportions are off (a bone seen end-on, a hidden end); it is not an error of "
    "the fitted joint angles, and it is not judged unless a bone_error_pct threshold is given."
)


@dataclass
class ValidationReport:
    """Per-joint errors (degrees, or mm for prismatic joints), reprojection (px), 3D error (mm and % of
    reach) and bone lengths (mm and %), with pass/fail against ``thresholds``."""

    joints: list[dict[str, Any]]
    bones: list[dict[str, Any]]
    reprojection_rms_px: float | None
    error_3d_mm: float | None
    error_3d_pct_reach: float | None
    reach_mm: float
    thresholds: dict[str, float]
    checks: dict[str, bool]
    message: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    #: without a truth: the fitted robot's mean distance from the monocular reconstruction (mm, after the
    #: fit's similarity); not an error (the reconstruction has its own) and not judged
    distance_to_reconstruction_mm: float | None = None
    #: without a truth: :func:`~chainspace.robot.uncertainty.camera_misfit` of the fit on its tracks
    tracks_misfit: float | None = None

    @property
    def passed(self) -> bool:
        """True when every judged check passes."""
        return all(self.checks.values())

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (floats, lists, dicts; inf thresholds as null)."""
        def clean(v):
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            if isinstance(v, (np.floating, float)):
                return float(v) if np.isfinite(v) else None
            if isinstance(v, (np.integer,)):
                return int(v)
            if isinstance(v, np.bool_):
                return bool(v)
            return v

        return clean({
            "passed": self.passed, "checks": self.checks, "thresholds": self.thresholds,
            "joints": self.joints, "bones": self.bones, "reprojection_rms_px": self.reprojection_rms_px,
            "error_3d_mm": self.error_3d_mm, "error_3d_pct_reach": self.error_3d_pct_reach,
            "reach_mm": self.reach_mm, "bones_note": BONES_NOTE, "message": self.message,
            "distance_to_reconstruction_mm": self.distance_to_reconstruction_mm, "tracks_misfit": self.tracks_misfit,
            **self.extra,
        })

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    def table(self) -> str:
        """The report as markdown: a joint table, a bone table and the checks."""
        out = ["| joint | status | RMS error | max error | reported std (median) | within 1 std |",
               "|---|---|---|---|---|---|"]
        for j in self.joints:
            unit = j.get("unit", "deg")
            sd = "-" if j.get("std_median") is None else f"{j['std_median']:.3f} {unit}"
            inside = "-" if j.get("within_1_std_pct") is None else f"{j['within_1_std_pct']:.0f} %"
            if j["rms"] is None:
                out.append(f"| {j['name']} | {j['status']} | - | - | {sd} | {inside} |")
            else:
                out.append(f"| {j['name']} | {j['status']} | {j['rms']:.3f} {unit} | {j['max']:.3f} {unit} | {sd} | "
                           f"{inside} |")
        out += ["", BONES_NOTE, "",
                "| bone | fitted robot (URDF) m | robot share % | reconstruction share % (scale-free) "
                "| share difference % |", "|---|---|---|---|---|"]
        for b in self.bones:
            rob = "-" if b.get("urdf_share_pct") is None else f"{b['urdf_share_pct']:.1f}"
            rec = "-" if b.get("reconstruction_share_pct") is None else f"{b['reconstruction_share_pct']:.1f}"
            diff = "-" if b.get("share_error_pct") is None else f"{b['share_error_pct']:+.1f}"
            out.append(f"| {b['name']} | {b['urdf_mm'] / 1000:.4f} | {rob} | {rec} | {diff} |")
        out.append("")
        why: dict[str, list[str]] = {}
        for b in self.bones:
            if b.get("not_compared"):
                why.setdefault(b["not_compared"], []).append(b["name"])
        for reason, names in why.items():  # the bones shown as "-", and why
            out.append(f"- not compared ({reason}, so no one length): {', '.join(names)}")
        rel = [j["name"] for j in self.joints if j.get("status") == "relative to frame 0"]
        amb = [j for j in self.joints if j.get("status") == "ambiguous"]
        if amb:
            from .uncertainty import AMBIGUOUS_DEG, UNCERTAIN_SIGMAS

            groups: dict[str, list[str]] = {}  # joints by reason, in order (a fit saved without per-joint
            for j in amb:                      # reasons gives its whole message for each)
                groups.setdefault(j.get("reason", ""), []).append(j["name"])
            out.append("- ambiguous, listed and not judged (another motion fits the tracks as well, the fit does not "
                       f"explain them, or {UNCERTAIN_SIGMAS:g} of the joint's standard deviations, plus its "
                       f"difference from such a motion, are more than {AMBIGUOUS_DEG:g} degrees): "
                       + "; ".join(f"{', '.join(n)}: {r}" if r else ", ".join(n) for r, n in groups.items()))
        if rel:
            out.append(f"- {', '.join(rel)}: seen only relative to frame 0 (a turn of the camera looks the same), "
                       "so compared, and plotted, as the change since frame 0")
        inside = [j["within_1_std_pct"] for j in self.joints
                  if j.get("judged") and j.get("within_1_std_pct") is not None]
        if inside and np.mean(inside) < STD_HONEST_PCT:
            out.append(f"- only {np.mean(inside):.0f} % of the true values lie within one reported standard deviation "
                       "(about 68 % if it held): the deviations assume independent pixel noise of the size the fit "
                       "measured, and these tracks' errors are larger or correlated (a tracker's bias follows a "
                       "point from frame to frame), so read them as a lower bound")
        if self.reprojection_rms_px is not None:
            out.append(f"- reprojection RMS: {self.reprojection_rms_px:.3f} px")
        if self.error_3d_mm is not None:
            out.append(f"- 3D error of the fitted robot: {self.error_3d_mm:.2f} mm "
                       f"({self.error_3d_pct_reach:.3f} % of the {self.reach_mm:.0f} mm reach)")
        if self.distance_to_reconstruction_mm is not None:
            out.append(f"- no truth given: the fitted robot lies {self.distance_to_reconstruction_mm:.1f} mm (mean) "
                       "from the monocular reconstruction, which has errors of its own (not judged)")
        if self.tracks_misfit is not None:
            out.append(f"- tracks_misfit {self.tracks_misfit:.2f}: the typical tracked point's residual over what "
                       "the tracks' own jitter allows a right fit (about 0.9 when the fit explains the tracks)")
        for name, ok in self.checks.items():
            t = self.thresholds.get(name)
            out.append(f"- {name} <= {t:g}: {'PASS' if ok else 'FAIL'}")
        out.append(f"- **{'PASSED' if self.passed else 'FAILED'}**" + (f" ({self.message})" if self.message else ""))
        return "\n".join(out)

    def __repr__(self) -> str:
        return f"ValidationReport(passed={self.passed}, checks={self.checks})"


def compared_differences(robot: Any, a: np.ndarray, ta: np.ndarray, relative: np.ndarray) -> np.ndarray:
    """(F, nv) fitted minus true per-dof coordinates a, ta (:meth:`RobotKinematics.angles`), turning
    joints wrapped; a joint seen only up to a constant (``relative`` (nv,)) compared without it: its
    circular mean for a turning joint, its mean for a sliding one."""
    d = robot.wrap_angles(a - ta)
    offset = np.where(robot.turns_v, np.angle(np.mean(np.exp(1j * d), axis=0)), d.mean(0))
    return np.where(relative, robot.wrap_angles(d - offset), d)


def validate(fit: Any, truth_q: Any = None, *, thresholds: dict[str, float] | None = None,
             truth_positions: Any = None) -> ValidationReport:
    """Validate a joint fit.

    Parameters
    ----------
    fit
        A :class:`chainspace.JointFit`.
    truth_q
        The true joint angles (F, nq) in Pinocchio order, or (F, nv) one angle per joint (radians,
        metres for prismatic joints; as ``fit.angles``), when known.
    thresholds
        Overrides of :data:`DEFAULT_THRESHOLDS`: ``joint_rms_deg`` (every judged joint),
        ``error_3d_pct_reach`` (3D error of the fitted robot against the truth; without one, against the
        3D points it was fitted to when it was fitted to 3D points alone), ``reprojection_rms_px``,
        ``bone_error_pct``, ``tracks_misfit`` (judged only without a truth, for a fit of 2D tracks:
        whether the fitted robot explains its tracks, :func:`~chainspace.robot.uncertainty.camera_misfit`;
        its distance from the monocular reconstruction is then reported, not judged, since the
        reconstruction has errors of its own: a UR5 fitted 0.8 mm from the truth lay 76 mm from it).
    truth_positions
        True 3D points (F, J, 3) in the robot's base frame, metres; default: forward kinematics of
        ``truth_q``.
    """
    if not hasattr(fit, "q") or not hasattr(fit, "joint_names"):
        raise TrackError(f"validate needs a JointFit, got {type(fit).__name__}")
    th = dict(DEFAULT_THRESHOLDS)
    for k, v in (thresholds or {}).items():
        if k not in DEFAULT_THRESHOLDS:
            raise DescriptionError(f"unknown threshold {k!r}; known: {', '.join(DEFAULT_THRESHOLDS)}")
        th[k] = float(v)
    robot = fit.kinematics()
    q = np.asarray(fit.q, float)
    F = len(q)
    tq = None
    if truth_q is not None:
        tq = np.asarray(truth_q, float)
        if tq.ndim == 2 and tq.shape == (F, robot.nv) and robot.nv != robot.nq:
            tq = robot.from_angles(tq)  # given as angles, one per joint (a saved joint_angles.csv)
        if tq.shape != q.shape:
            raise TrackError(f"truth_q has shape {tq.shape}, the fit's q {q.shape} (or angles ({F}, {robot.nv}))")
    joints = _joint_errors(robot, fit, q, tq)

    # 3D error of the fitted robot (base frame) against the truth; else how far from the reconstruction
    reach = robot.reach()
    pos = fit.positions_base if fit.positions_base is not None else robot.positions(q)
    err3 = distance = misfit = None
    if truth_positions is not None or tq is not None:
        tp = robot.positions(tq) if truth_positions is None else np.asarray(truth_positions, float)
        if tp.shape != pos.shape:
            raise TrackError(f"truth_positions have shape {tp.shape}, expected {pos.shape}")
        from .views import similarity_align

        # the base frame is known up to the first joint's turn when that joint is relative: align rigidly
        _, R, t = similarity_align(pos, tp, scale=False)
        err3 = float(np.nanmean(np.linalg.norm(pos @ R.T + t - tp, axis=-1)))
    elif fit.residual_3d is not None and fit.scale:
        misfit = _tracks_misfit(fit)
        if misfit is None:  # fitted to 3D points alone (motion capture): their distance is the error
            err3 = float(np.nanmean(fit.residual_3d) / fit.scale)
        else:  # to a monocular reconstruction of tracks: that has errors of its own, the tracks judge
            distance = float(np.nanmean(fit.residual_3d) / fit.scale)
    bones = _bone_errors(robot, fit)
    rep = reprojection_rms(fit)

    checks: dict[str, bool] = {}
    judged = [j for j in joints if j["judged"]]
    if tq is not None and judged:
        checks["joint_rms_deg"] = all(j["rms"] <= th["joint_rms_deg"] for j in judged)
    if err3 is not None:
        checks["error_3d_pct_reach"] = 100 * err3 / reach <= th["error_3d_pct_reach"]
    if misfit is not None and np.isfinite(th["tracks_misfit"]):
        checks["tracks_misfit"] = misfit <= th["tracks_misfit"]
    if rep is not None and np.isfinite(th["reprojection_rms_px"]):
        checks["reprojection_rms_px"] = rep <= th["reprojection_rms_px"]
    if np.isfinite(th["bone_error_pct"]):
        errs = [abs(b["error_pct"]) for b in bones if b["error_pct"] is not None]
        checks["bone_error_pct"] = bool(errs) and max(errs) <= th["bone_error_pct"]
    failing = [j["name"] for j in judged if tq is not None and j["rms"] > th["joint_rms_deg"]]
    msg = f"joints over {th['joint_rms_deg']:g} deg RMS: {', '.join(failing)}" if failing else ""
    return ValidationReport(
        joints=joints, bones=bones, reprojection_rms_px=rep,
        error_3d_mm=None if err3 is None else 1000 * err3,
        error_3d_pct_reach=None if err3 is None else 100 * err3 / reach, reach_mm=1000 * reach,
        thresholds=th, checks=checks, message=msg, extra={"n_frames": F, "fit_message": fit.message},
        distance_to_reconstruction_mm=None if distance is None else 1000 * distance, tracks_misfit=misfit,
    )


def _tracks_misfit(fit: Any) -> float | None:
    """camera_misfit of the fit's reprojection on its tracks; None without tracks, a camera, or enough
    frames to measure the tracks' jitter."""
    seen = None if fit.tracks is None else fit.reprojected()
    if seen is None:
        return None
    tracks = np.asarray(fit.tracks, float)
    w = _weights(tracks, None if fit.confidence is None else np.asarray(fit.confidence, float))
    ratio = camera_misfit(np.linalg.norm(seen - np.nan_to_num(tracks), axis=-1), w, track_jitter(tracks, w))[0]
    return float(ratio) if np.isfinite(ratio) else None


def _joint_errors(robot, fit, q, tq) -> list[dict[str, Any]]:
    """One row per degree of freedom (``fit.joint_names``): angles compared in radians (a continuous
    joint's (cos, sin) as one angle, :meth:`RobotKinematics.angles`), prismatic joints in metres."""
    out = []
    a = robot.angles(q)
    ta = None if tq is None else robot.angles(tq)
    names = list(fit.joint_names) if len(fit.joint_names) == robot.nv else list(robot.joint_names)
    observable = np.asarray(fit.observable, bool).reshape(-1)
    if observable.size != robot.nv:  # a fit saved with one flag per q entry: flags of each joint's first entry
        first = [int(np.flatnonzero(robot._qv[:, v])[0]) for v in range(robot.nv)]
        observable = observable[first]
        saved = getattr(fit, "relative", None)
        relative = np.zeros(0, bool) if saved is None else np.asarray(saved, bool).reshape(-1)
        relative = relative[first] if relative.size else np.zeros(robot.nv, bool)
    else:
        relative = joint_flags(fit, "relative", len(names))
    ambiguous = joint_flags(fit, "ambiguous", len(names))
    reasons = joint_reasons(fit)  # why each flagged joint is: the fit's own words for that joint
    std = getattr(fit, "q_std", None)
    std = np.asarray(std, float) if std is not None and np.shape(std) == (len(q), len(names)) else None
    if ta is not None:
        d_all = robot.wrap_angles(a - ta)
        # against the deviations as reported: a relative joint's are of its change since frame 0
        d_std = np.where(relative, robot.wrap_angles(d_all - d_all[0]), d_all)
        d_rms = compared_differences(robot, a, ta, relative)
    for k, name in enumerate(names):
        obs, rel = bool(observable[k]), bool(relative[k])
        status = "observable" if obs else ("relative to frame 0" if rel else "not observable")
        if ambiguous[k]:
            status = "ambiguous"
        row: dict[str, Any] = {"name": name, "status": status, "judged": (obs or rel) and not ambiguous[k],
                               "rms": None, "max": None, "unit": "mm" if robot.prismatic_v[k] else "deg"}
        scale = np.degrees(1.0) if row["unit"] == "deg" else 1000.0
        if ambiguous[k]:
            row["reason"] = reasons[k]
        if std is not None and np.isfinite(std[:, k]).any():
            row["std_median"] = float(np.nanmedian(std[:, k]) * scale)
        if ta is not None and (obs or rel or ambiguous[k]):
            if std is not None and np.isfinite(std[:, k]).any():
                ok = np.isfinite(std[:, k]) & (std[:, k] > 0)
                row["within_1_std_pct"] = float(100 * np.mean(np.abs(d_std[ok, k]) <= std[ok, k])) if ok.any() else None
            d = d_rms[:, k]
            row["rms"] = float(np.sqrt(np.mean(d ** 2)) * scale)
            row["max"] = float(np.abs(d).max() * scale)
        out.append(row)
    return out


def _bone_errors(robot, fit) -> list[dict[str, Any]]:
    """Bone lengths of the reconstruction (scaled into metres by the fit's similarity) against the URDF's."""
    chain = fit.chain
    urdf_len = chain.bone_lengths(robot.positions(robot.q_rest)[0])
    rec = None
    poses = getattr(fit, "input_poses", None)
    if poses is not None and fit.scale:
        rec = np.nanmedian(chain.bone_lengths(poses), axis=0) / fit.scale
    rows = []
    variable = {tuple(v) for v in chain.metadata.get("variable_bones", [])}
    # a bone across a prismatic joint has no one length to compare: reported, not judged
    judged = np.array([(a, b) not in variable for a, b in chain.links], bool)
    ok = (np.isfinite(rec) & judged) if rec is not None else np.zeros(len(urdf_len), bool)
    urdf_total, rec_total = float(np.sum(urdf_len[ok])), float(np.sum(rec[ok])) if ok.any() else 0.0
    for k, (a, b) in enumerate(chain.links):
        L = float(urdf_len[k])
        r = float(rec[k]) if ok[k] else None
        # shares of the total over the bones the reconstruction has: scale-free, so comparable
        us = 100 * L / urdf_total if r is not None and urdf_total > 0 else None
        rs = 100 * r / rec_total if r is not None and rec_total > 0 else None
        why = None if r is not None else ("its ends lie on links that move against each other" if not judged[k] else
                                          "not in the reconstruction" if rec is None or not np.isfinite(rec[k])
                                          else "")
        rows.append({"name": f"{a}-{b}", "urdf_mm": 1000 * L, "recovered_mm": None if r is None else 1000 * r,
                     "not_compared": why,
                     "error_mm": None if r is None else 1000 * (r - L),
                     "error_pct": None if r is None or L < 1e-9 else 100 * (r - L) / L,
                     "urdf_share_pct": us, "reconstruction_share_pct": rs,
                     "share_error_pct": None if us is None or rs is None or us < 1e-9 else 100 * (rs - us) / us})
    return rows
