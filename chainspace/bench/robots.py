"""The robot benchmark: tracks of known robot motion in, joint angles out, checked against the truth.

For the milling arm (robots/), the UR10, Panda and xArm7 of example-robot-data, the Kinova Gen2
(continuous joints) and the milling arm on its floor track (a prismatic axis, robots/): 300-frame random
smooth trajectories inside the joint limits, a static weak-perspective camera (``synthesize(camera=
"static")``: these rows measure the weak-perspective fit; bench_pinhole_robots.py and bench_full_range.py
film with pinhole cameras) at a random view, the robot spanning about 800 px, 0, 1 and 3 px noise, and per-frame cameras at 1 px. Each trial goes the user's way:
:func:`chainspace.reconstruct` on the tracks alone, then :func:`chainspace.fit_joint_angles` with the
URDF. Reported: the worst per-joint RMS error (degrees) over the observable joints (joints seen only
relative to the first frame included, after removing their offset), the 3D error of the fitted robot
(mm and % of reach), and frames per second of reconstruction plus fit.

Targets (issue 4): joint RMS <= 1 degree on every observable joint and 3D error <= 1 % of reach at
1 px with a static camera.

Command: ``python benchmarks/bench_robots.py`` (``--quick`` for a short run) or ``chainspace bench``.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["ROBOTS", "ROBOT_NAMES", "robot_chain", "run_robot_benchmark", "format_robot_table", "trial_errors"]

# tracked points per robot: every link origin (the URDF's own points); the Panda without its fingers
# (a gripper's fingers are rarely trackable), which leaves its flange joint unobservable. The two
# 7-axis arms have a ball-like shoulder whose centre and first axis carry every base point: the arm
# beyond it then has an exact depth mirror under weak perspective (fitting every track alike), so
# they also track a marker on the first link's housing, off its axis (see chainspace.robot.fit's docstring).
ROBOTS: dict[str, dict[str, Any]] = {
    "milling arm": {"urdf": "milling_arm", "links": None},
    "UR10": {"urdf": "ur10", "links": None},
    "Panda": {"urdf": "panda", "links": ["panda_link0", "panda_link1", "panda_link3", "panda_link4",
                                         "panda_link5", "panda_link7", "panda_link8", "panda_hand_tcp",
                                         "shoulder_marker"],
              "extra_frames": {"shoulder_marker": ("panda_link1", [0.08, 0.0, -0.1])}},
    "xArm7": {"urdf": "xarm7", "links": None,
              "extra_frames": {"shoulder_marker": ("link1", [0.08, 0.0, -0.05]),
                               "tool_marker": ("link7", [0.05, 0.0, 0.03])}},
    # continuous joints (Pinocchio's q holds (cos, sin) for joints 1, 4 and 6; errors are per angle)
    "Kinova": {"urdf": "kinova", "links": None},
    # a prismatic 7th axis (the floor track, reported in metres; its row's joint error is over the
    # six angles, the track's own error in mm is in the validation report)
    "milling arm on track": {"urdf": "milling_arm_on_track", "links": None},
}
SHIPPED = ("milling_arm", "milling_arm_on_track")  # robots/ rather than example-robot-data


def _names() -> list[str]:
    from ..io.descriptions import EXAMPLE_ROBOTS

    return list(ROBOTS) + [n for n in EXAMPLE_ROBOTS if n not in ROBOTS]


ROBOT_NAMES = _names()  # what --robots accepts: the table's robots, then any example-robot-data name

CONDITIONS = [("static", 0.0), ("static", 1.0), ("static", 3.0), ("per-frame", 1.0)]


def robot_chain(name: str):
    """The chain of benchmark robot ``name``: a key of :data:`ROBOTS`, else any example-robot-data name
    (:data:`chainspace.EXAMPLE_ROBOTS`, every link origin tracked; the tests use the double pendulum)."""
    from ..io.descriptions import example_robot_urdf, shipped_path
    from ..io.urdf import from_urdf

    spec = ROBOTS.get(name, {"urdf": name, "links": None})
    path = shipped_path(spec["urdf"]) if spec["urdf"] in SHIPPED else example_robot_urdf(spec["urdf"])
    return from_urdf(path, links=spec["links"], extra_frames=spec.get("extra_frames"))


def trial_errors(fit: Any, trial: Any) -> tuple[float, float]:
    """(worst per-joint RMS degrees over judged revolute and continuous joints (prismatic ones, in mm,
    are left to the validation report), mean 3D error of the fitted robot in metres)."""
    from ..robot.validation import validate

    rep = validate(fit, trial.q, truth_positions=trial.positions)
    judged = [j["rms"] for j in rep.joints if j["judged"] and j["rms"] is not None and j["unit"] == "deg"]
    return (max(judged) if judged else float("nan")), rep.error_3d_mm / 1000.0


def _prismatic_mm(fit: Any, trial: Any) -> float:
    """Worst RMS error (mm) over the judged prismatic joints; NaN when there are none."""
    from ..robot.validation import validate

    rep = validate(fit, trial.q)
    mm = [j["rms"] for j in rep.joints if j["judged"] and j["rms"] is not None and j["unit"] == "mm"]
    return max(mm) if mm else float("nan")


def run_robot_benchmark(quick: bool = False, progress: Callable[[str], None] | None = None, *,
                        robots: list[str] | None = None, n_frames: int | None = None, seeds: int | None = None,
                        conditions: list[tuple[str, float]] | None = None) -> list[dict[str, Any]]:
    """Run the benchmark; one row per robot and condition (camera, noise px), averaged over seeds.

    ``quick``: 60 frames, one seed, the target condition only (static camera, 1 px). Rows hold: robot, camera, noise_px, joint_rms_deg (worst joint,
    mean over seeds), joint_rms_deg_max (worst seed), error_3d_mm, error_3d_pct, fps, reach_mm,
    n_frames, seeds, unobservable (joint names).
    """
    from ..robot.kinematics import RobotKinematics
    from ..robot.fit import fit_joint_angles
    from ..reconstruction.pipeline import reconstruct
    from ..synthetic.robot import synthesize

    n_frames = n_frames or (60 if quick else 300)
    seeds = seeds or (1 if quick else 3)
    conditions = conditions or ([("static", 1.0)] if quick else CONDITIONS)
    rows = []
    for name in robots or list(ROBOTS):
        chain = robot_chain(name)
        reach = RobotKinematics(chain.metadata["urdf_path"], chain).reach()
        for camera, noise in conditions:
            errs, e3, secs, unobs, mm = [], [], 0.0, set(), []
            for seed in range(seeds):
                trial = synthesize(chain, n_frames=n_frames, noise_px=noise, seed=seed, camera="static")
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    rec = reconstruct(trial.tracks, chain, seed=seed)
                    fit = fit_joint_angles(rec, camera=camera)
                secs += time.perf_counter() - t0
                j, e = trial_errors(fit, trial)
                errs.append(j)
                e3.append(e)
                mm += [_prismatic_mm(fit, trial)]
                unobs |= {n for n, o, r in zip(fit.joint_names, fit.observable, fit.relative) if not (o or r)}
            row = {"robot": name, "camera": camera, "noise_px": noise, "joint_rms_deg": float(np.mean(errs)),
                   "joint_rms_deg_max": float(np.max(errs)), "error_3d_mm": 1000 * float(np.mean(e3)),
                   "error_3d_pct": 100 * float(np.mean(e3)) / reach, "fps": seeds * n_frames / secs,
                   "reach_mm": 1000 * reach, "n_frames": n_frames, "seeds": seeds,
                   "unobservable": sorted(unobs),
                   "prismatic_rms_mm": float(np.mean(mm)) if np.isfinite(mm).all() else None}
            rows.append(row)
            if progress:
                progress(f"{name:12s} {camera:9s} {noise:3.0f} px: worst joint {row['joint_rms_deg']:.3f} deg, "
                         f"3D {row['error_3d_mm']:.1f} mm ({row['error_3d_pct']:.2f} %), {row['fps']:.0f} frames/s")
    return rows


def format_robot_table(rows: list[dict[str, Any]]) -> str:
    """The rows as one markdown table."""
    out = ["| robot | camera | noise px | worst joint RMS deg (mean / worst seed) | 3D error mm | % of reach | "
           "frames/s | not observable |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = r["joint_rms_deg"] <= 1.0 and r["error_3d_pct"] <= 1.0
        mark = "" if r["noise_px"] != 1.0 or r["camera"] != "static" else (" (target met)" if ok else " (target missed)")
        if r.get("prismatic_rms_mm") is not None:  # a linear axis: its error in mm, beside the angles
            mark += f"; prismatic {r['prismatic_rms_mm']:.2f} mm"
        out.append(f"| {r['robot']} | {r['camera']} | {r['noise_px']:g} | {r['joint_rms_deg']:.3f} / "
                   f"{r['joint_rms_deg_max']:.3f}{mark} | {r['error_3d_mm']:.1f} | {r['error_3d_pct']:.3f} | "
                   f"{r['fps']:.0f} | {', '.join(r['unobservable']) or '-'} |")
    n = rows[0]["n_frames"] if rows else 0
    s = rows[0]["seeds"] if rows else 0
    out.append(f"\n{n} frames, {s} seed(s) per row; reconstruct (tracks only) + fit_joint_angles; targets at 1 px "
               "static: worst joint <= 1 deg RMS, 3D error <= 1 % of reach.")
    return "\n".join(out)
