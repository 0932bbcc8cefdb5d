"""No silent failure (issue 21): robots over their full joint ranges, cameras above and below the base.

For every robot of example-robot-data with a fixed base (arms) or legs, and the shipped milling arm:
:func:`chainspace.synthesize` moves every joint over its whole range (URDF limits, continuous joints
+-180 degrees; ``joint_range="full"``) or through a singularity (``trajectory="singular"``), and films
it with one static camera (the default realistic pinhole camera, or weak perspective with ``camera=
"static"``) from above the base plane (elevation random in 10-35 degrees) and from 20 degrees below it
(a ceiling-mounted robot, a low tripod), 1 px noise. Each run goes the user's way with the defaults:
:func:`chainspace.reconstruct` on the tracks, then :func:`chainspace.fit_joint_angles` (given the
camera's intrinsics and the tracks for a pinhole camera).

Each joint of each run gets one verdict:

* ``ok``: within :data:`JOINT_DEG` degrees RMS of the truth (a joint reported relative to frame 0 is
  compared after removing its mean offset, as :func:`chainspace.validate` does, also when flagged; a prismatic joint within
  :data:`JOINT_MM` mm);
* ``flagged``: the fit's report gives it any status other than "observable" or "relative to frame 0"
  (not observable, ambiguous, ...), read from :func:`chainspace.validate`'s joint rows: its reason is
  that status and the fit's message. A flipped wrist that moves no tracked point counts as right only
  so;
* ``silent``: reported observable (or relative) and off by more than the tolerance: a silent failure.

A run that raises counts in its own column: ``refused`` (a :class:`~chainspace.errors.ChainspaceError`,
which names what is unsupported) or ``crashed`` (anything else). Every run counts in every mean and
maximum: the worst-joint columns are over every judged joint of every run that returned a fit, flagged
joints in their own column.

Target (issue 21): per robot, every joint within 2 degrees RMS or flagged with a reason, no crash.

Command: ``python benchmarks/bench_full_range.py`` (60 frames, one seed by default; ``--quick``: 2 robots,
20 frames).
"""

from __future__ import annotations

import time
import traceback
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..errors import ChainspaceError

__all__ = ["ROBOTS", "SETTINGS", "JOINT_DEG", "JOINT_MM", "judge_joints", "run_full_range", "format_full_range",
           "full_range_chain"]

JOINT_DEG, JOINT_MM = 2.0, 2.0
JUDGED = ("observable", "relative to frame 0")  # any other status is a flag with a reason
# example-robot-data names (chainspace.EXAMPLE_ROBOTS) with a fixed base or legs, and the shipped arm;
# Baxter (two arms, 17 joints, 51 points) is left to --robots: one run takes longer than the rest together
ROBOTS = ("milling_arm", "ur3", "ur5", "ur10", "panda", "xarm7", "kinova", "z1", "so100", "so101", "talos_arm",
          "double_pendulum", "a1", "go1", "solo12", "laikago")
# name -> synthesize options: full ranges seen from above and from below, and a path through a singularity
SETTINGS: dict[str, dict[str, Any]] = {
    "full, above": dict(joint_range="full", elevation_deg=None),
    "full, below": dict(joint_range="full", elevation_deg=-20.0),
    "singular, above": dict(trajectory="singular", elevation_deg=None),
}
DEFAULT_SETTINGS = ("full, above", "full, below")


def full_range_chain(name: str):
    """The chain of robot ``name`` as a user gets it: every link origin of its URDF tracked."""
    from ..io.descriptions import example_robot_urdf, shipped_path
    from ..io.urdf import from_urdf

    return from_urdf(shipped_path(name) if name == "milling_arm" else example_robot_urdf(name))


def judge_joints(fit: Any, trial: Any) -> list[dict[str, Any]]:
    """One row per joint (degree of freedom): name, status (the fit's report), error (RMS, degrees or mm,
    of every joint whatever its status), std (the fit's standard deviation, RMS over the frames, same unit;
    None where it gives none), alternative (the largest RMS difference from it of an alternative that fits as
    well and nothing settled, same unit; 0 without one), unit, verdict ("ok", "flagged" or "silent") and
    reason. The last two let a flagging rule be weighed on kept runs."""
    from ..robot.result import joint_flags
    from ..robot.uncertainty import ambiguous_joints, uncertain_joints
    from ..robot.validation import compared_differences, validate

    rep = validate(fit, trial.q)
    robot = fit.kinematics()
    a, ta = robot.angles(np.asarray(fit.q, float)), robot.angles(np.asarray(trial.q, float))
    relative = joint_flags(fit, "relative", robot.nv)
    diff = compared_differences(robot, a, ta, relative)  # a relative joint without its offset, also when flagged
    q_std = getattr(fit, "q_std", None)
    spread = np.full(robot.nv, np.nan) if q_std is None else \
        uncertain_joints(robot, np.asarray(q_std, float), np.ones(robot.nv, bool))[1]
    apart = ambiguous_joints(robot, a, list(getattr(fit, "alternatives", None) or []), np.ones(robot.nv, bool),
                             relative)[1]
    rows = []
    for k, j in enumerate(rep.joints):
        status = str(j["status"])
        d = diff[:, k]
        prismatic = bool(robot.prismatic_v[k])
        err = float(np.sqrt(np.mean(d ** 2)) * (1000.0 if prismatic else np.degrees(1.0)))
        tol = JOINT_MM if prismatic else JOINT_DEG
        if err <= tol:
            verdict, reason = "ok", ""
        elif status not in JUDGED:  # the fit's own words for this joint (validate's row)
            verdict, reason = "flagged", status + (f" ({j['reason'][:160]})" if j.get("reason") else "")
        else:
            verdict, reason = "silent", f"reported {status}"
        rows.append(dict(name=j["name"], status=status, error=err,
                         std=float(spread[k]) if np.isfinite(spread[k]) else None, alternative=float(apart[k]),
                         unit="mm" if prismatic else "deg",
                         verdict=verdict, reason=reason))
    return rows


def _film(chain: Any, setting: str, camera: str, n_frames: int, seed: int):
    from ..synthetic.robot import synthesize

    return synthesize(chain, n_frames=n_frames, noise_px=1.0, seed=seed, camera=camera, **SETTINGS[setting])


def _fit(chain: Any, trial: Any, seed: int, search_ties: bool = True, view_from: str = "above"):
    from ..reconstruction.pipeline import reconstruct
    from ..robot.fit import fit_joint_angles

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(trial.tracks, chain, seed=seed)
        if trial.intrinsics is None:  # the side a weak camera stands on is the user's to say: the side filmed from
            return fit_joint_angles(rec, search_ties=search_ties, view_from=view_from)
        return fit_joint_angles(rec, tracks=trial.tracks, intrinsics=trial.intrinsics, search_ties=search_ties)


def run_full_range(robots: Sequence[str] = ROBOTS, settings: Sequence[str] = DEFAULT_SETTINGS, *,
                   camera: str = "pinhole", n_frames: int = 60, seeds: int = 1, first_seed: int = 0,
                   search_ties: bool = True, progress: Callable[[str], None] | None = None,
                   on_run: Callable[[list[dict[str, Any]]], None] | None = None) -> list[dict[str, Any]]:
    """One row per run (robot, setting, seed): robot, setting, seed, outcome ("fit", "refused",
    "crashed"), joints (see :func:`judge_joints`; empty without a fit), error_3d_mm, seconds, note.
    Seeds ``first_seed`` to ``first_seed + seeds - 1`` (seeds set aside while tuning stay reachable).
    ``on_run(runs)`` is called after every run with the runs so far (to save them as they come)."""
    from ..robot.kinematics import RobotKinematics

    runs = []
    for name in robots:
        try:
            chain = full_range_chain(name)
            reach = RobotKinematics(chain.metadata["urdf_path"], chain).reach()
        except Exception as exc:  # the robot cannot even be loaded: every run of it counts as failed
            for setting in settings:
                for seed in range(first_seed, first_seed + seeds):
                    runs.append(dict(robot=name, setting=setting, seed=seed, outcome=_outcome(exc), joints=[],
                                     error_3d_mm=np.nan, reach_mm=np.nan, seconds=0.0, note=_note(exc)))
            continue
        for setting in settings:
            for seed in range(first_seed, first_seed + seeds):
                t0 = time.perf_counter()
                row = dict(robot=name, setting=setting, seed=seed, reach_mm=1000 * reach)
                try:
                    trial = _film(chain, setting, camera, n_frames, seed)
                    fit = _fit(chain, trial, seed, search_ties, view_from=setting.rsplit(", ", 1)[1])
                    row.update(outcome="fit", joints=judge_joints(fit, trial),
                               error_3d_mm=_error_3d_mm(fit, trial), note=fit.message)
                except Exception as exc:
                    row.update(outcome=_outcome(exc), joints=[], error_3d_mm=np.nan, note=_note(exc))
                    if progress and row["outcome"] == "crashed":
                        progress(traceback.format_exc())
                row["seconds"] = time.perf_counter() - t0
                runs.append(row)
                if progress:
                    progress(_run_line(row))
                if on_run:
                    on_run(runs)
    return runs


def _outcome(exc: BaseException) -> str:
    return "refused" if isinstance(exc, ChainspaceError) else "crashed"


def _note(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _error_3d_mm(fit: Any, trial: Any) -> float:
    from ..robot.validation import validate

    rep = validate(fit, trial.q, truth_positions=trial.positions)
    return float("nan") if rep.error_3d_mm is None else float(rep.error_3d_mm)


def _run_line(r: dict[str, Any]) -> str:
    if r["outcome"] != "fit":
        return f"{r['robot']} {r['setting']} seed {r['seed']}: {r['outcome']}: {r['note'][:200]}"
    bad = [f"{j['name']} {j['error']:.1f} {j['unit']} ({j['verdict']}: {j['reason']})" for j in r["joints"]
           if j["verdict"] != "ok"]
    return (f"{r['robot']} {r['setting']} seed {r['seed']}: {r['seconds']:.0f} s, 3D {r['error_3d_mm']:.1f} mm; "
            + ("; ".join(bad) if bad else "every joint within tolerance"))


def _stats(values: list[float]) -> str:
    v = np.asarray(values, float)
    if v.size == 0:
        return "-"
    if not np.isfinite(v).all():
        return f"nan in {int((~np.isfinite(v)).sum())}"
    return f"{v.mean():.2f} / {v.max():.2f}"


def _verdict_counts(joints: Sequence[dict[str, Any]]) -> dict[str, int]:
    """How many of the judged joints (:func:`judge_joints`' rows) are ok, flagged and silent."""
    return {v: sum(j["verdict"] == v for j in joints) for v in ("ok", "flagged", "silent")}


def summarise(runs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per robot: runs, fitted, refused, crashed, joint verdict counts, worst judged joint per run (mean /
    max over every fitted run), worst flagged joint, 3D error, and whether the target is met."""
    out = []
    for name in dict.fromkeys(r["robot"] for r in runs):
        rs = [r for r in runs if r["robot"] == name]
        fitted = [r for r in rs if r["outcome"] == "fit"]
        joints = [j for r in fitted for j in r["joints"]]
        count = _verdict_counts(joints)
        judged = [max([j["error"] for j in r["joints"] if j["verdict"] != "flagged" and j["unit"] == "deg"],
                      default=0.0) for r in fitted]
        flagged = [j["error"] for j in joints if j["verdict"] == "flagged" and j["unit"] == "deg"]
        refused = sum(r["outcome"] == "refused" for r in rs)
        crashed = sum(r["outcome"] == "crashed" for r in rs)
        met = count["silent"] == 0 and crashed == 0 and bool(fitted)
        verdict = ("met" if met and not refused else "met (some runs refused)" if met else
                   "missed" if count["silent"] or crashed else "refused")
        out.append(dict(robot=name, runs=len(rs), fitted=len(fitted), refused=refused, crashed=crashed, **count,
                        judged=judged, flagged_errors=flagged, error_3d=[r["error_3d_mm"] for r in fitted],
                        verdict=verdict,
                        silent_joints=sorted({f"{j['name']} ({r['setting']}, {j['error']:.0f} deg)" for r in fitted
                                              for j in r["joints"] if j["verdict"] == "silent"}),
                        flags=sorted({f"{j['name']}: {j['reason']}" for r in fitted for j in r["joints"]
                                      if j["verdict"] == "flagged"}),
                        failures=[f"{r['setting']} seed {r['seed']}: {r['outcome']}: {r['note'][:160]}"
                                  for r in rs if r["outcome"] != "fit"]))
    return out


def format_full_range(runs: Sequence[dict[str, Any]], *, camera: str = "pinhole", n_frames: int | None = None) -> str:
    """Markdown: one line per robot, then the silent failures, the flags with their reasons and the failed
    runs, each named."""
    rows = summarise(runs)
    settings = ", ".join(dict.fromkeys(r["setting"] for r in runs))
    out = [f"Settings: {settings}; camera {camera}; 1 px noise"
           + (f"; {n_frames} frames per run" if n_frames else "") + ". Cells a / b: mean / max over every "
           "fitted run. Joint verdicts: ok (within 2 deg RMS), flagged (any status but observable: counted "
           "right), silent (reported observable and off: a silent failure).", "",
           "| robot | runs | fitted | refused | crashed | joints ok | flagged | silent | worst judged joint deg "
           "| worst flagged joint deg | 3D error mm | target |", "|---|---:|---:|---:|---:|---:|---:|---:|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['robot']} | {r['runs']} | {r['fitted']} | {r['refused']} | {r['crashed']} | {r['ok']} | "
                   f"{r['flagged']} | {r['silent']} | {_stats(r['judged'])} | {_stats(r['flagged_errors'])} | "
                   f"{_stats(r['error_3d'])} | {r['verdict']} |")
    met = sum(r["verdict"].startswith("met") for r in rows)
    out.append(f"\nTarget met on {met} of {len(rows)} robots.")
    silent = [f"- {r['robot']}: {', '.join(r['silent_joints'])}" for r in rows if r["silent_joints"]]
    flags = [f"- {r['robot']}: " + "; ".join(f[:200] for f in r["flags"]) for r in rows if r["flags"]]
    fails = [f"- {r['robot']} {f}" for r in rows for f in r["failures"]]
    for title, lines in (("Silent failures (joint, setting, RMS error)", silent), ("Flagged joints and why", flags),
                         ("Runs that returned no fit", fails)):
        if lines:
            out += ["", f"{title}:"] + lines
    return "\n".join(out)


def _run_summary(r: dict[str, Any]) -> tuple:
    """(outcome, silent joints, flagged joints, worst joint judged ok (deg)) of one run."""
    if r["outcome"] != "fit":
        return r["outcome"], (), (), 0.0
    silent, flagged = (tuple(sorted(j["name"] for j in r["joints"] if j["verdict"] == v))
                       for v in ("silent", "flagged"))
    worst = max([j["error"] for j in r["joints"] if j["verdict"] == "ok" and j["unit"] == "deg"], default=0.0)
    return "fit", silent, flagged, worst


def compare_full_range(old: Sequence[dict[str, Any]], new: Sequence[dict[str, Any]], moved_deg: float = 0.5) -> str:
    """Markdown: two sets of runs of the same robots, settings and seeds (two builds), side by side: per
    set the joints ok, flagged and silent, the runs with a silent joint, those with a poor fit flagged and
    those that returned no fit; then every run whose silent or flagged joints changed or whose worst joint
    judged ok moved by more than ``moved_deg``, and the runs found in one set only. Why: a change to the
    solver moves a hard case's outcome one way or the other, and only the counts over every run say
    which way the change leans."""
    def key(r):
        return r["robot"], r["setting"], r["seed"]

    sets = [{key(r): r for r in runs} for runs in (old, new)]
    out = ["| set | runs | joints ok | flagged | silent | runs with a silent joint | runs flagged poor fit | no fit |",
           "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for label, runs in zip(("old", "new"), sets):
        count = _verdict_counts([j for r in runs.values() for j in r["joints"]])
        silent_runs = sum(bool(_run_summary(r)[1]) for r in runs.values())
        poor = sum(any("poor fit" in j["reason"] for j in r["joints"]) for r in runs.values())
        no_fit = sum(r["outcome"] != "fit" for r in runs.values())
        out.append(f"| {label} | {len(runs)} | {count['ok']} | {count['flagged']} | {count['silent']} | "
                   f"{silent_runs} | {poor} | {no_fit} |")
    common, changed = sorted(set(sets[0]) & set(sets[1]), key=str), []
    for k in common:
        a, b = (_run_summary(s[k]) for s in sets)
        if a[:3] != b[:3] or abs(a[3] - b[3]) > moved_deg:
            changed.append(f"- {k[0]} {k[1]} seed {k[2]}: " + "; ".join(
                f"{label} {o}, silent {', '.join(sl) or '-'}, flagged {', '.join(fl) or '-'}, worst ok {w:.2f} deg"
                for label, (o, sl, fl, w) in zip(("old", "new"), (a, b))))
    only = [f"- {k[0]} {k[1]} seed {k[2]}: only in the {label} set" for label, s, t in
            (("old", sets[0], sets[1]), ("new", sets[1], sets[0])) for k in sorted(set(s) - set(t), key=str)]
    out += ["", f"Runs that changed ({len(changed)} of {len(common)}):"] + (changed or ["- none"])
    return "\n".join(out + ([""] + only if only else []))
