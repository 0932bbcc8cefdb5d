"""How the robot fit carries joints hidden at the start or the end of a sequence.

Before a joint's first sighting and after its last one nothing but the motion prior places it. The
acceleration prior alone (the default) carries it on at its last speed for ever; ``fit_joint_angles``
can also let the speed decay there (``speed_decay_s``). This benchmark measures that choice on trials
the robustness benchmark does not use: the milling arm (with its spindle marker), smooth random joint
motion, 90 frames at 30 fps, 2 px noise, the tracked 3D positions and the tracks given to the fit, and
the wrist and tool points hidden for the first or the last second.

Reported per setting of ``speed_decay_s``: the worst per-joint RMS error (degrees) and the 3D error of
the fitted robot (mm), as :func:`chainspace.bench.robots.trial_errors` measures them, mean and maximum
over EVERY run. A run whose worst joint is off by more than 90 degrees has its wrist on the flipped
branch (a4 + 180, a5 mirrored, a6 + 180: every tracked point in the same place), which the rest-pose
rule settles, not the prior; such runs are counted in their own column too (never instead: an earlier
version of this table left a 177-degree run out of the mean and maximum, which reversed its
conclusion), and so are runs with a silent failure (a joint reported observable and more than 2
degrees off: :func:`chainspace.bench.full_range.judge_joints`; a flip counts as right only when the
fit flagged the joint).

Command: ``python benchmarks/bench_hidden_ends.py`` (``--quick``: 2 trials) or
``chainspace bench --suite hidden-ends``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ["DECAYS", "run_hidden_ends", "format_hidden_ends"]

DECAYS: tuple[float | None, ...] = (None, 0.5)  # speed_decay_s; None: no decay
WRIST = ("link_5", "link_6", "spindle", "tool_tip", "tool_marker")
FLIPPED_DEG = 90.0


def run_hidden_ends(quick: bool = False, progress: Callable[[str], None] | None = None, *,
                    n_trials: int | None = None, decays: Sequence[float | None] = DECAYS, n_frames: int = 90,
                    hidden_frames: int = 30, noise_px: float = 2.0, robot: str = "milling_arm") -> list[dict[str, Any]]:
    """One row per trial, hidden end and decay: trial, end ("first"/"last"), decay, worst_deg, error_mm,
    silent (joints off and reported observable). ``quick``: 2 trials, else 8 (``n_trials``). ``robot``:
    the milling arm (its wrist and tool points hidden), or an example-robot-data name (the deepest third
    of its points hidden; the tests use the double pendulum)."""
    from .full_range import judge_joints
    from .robots import trial_errors
    from .robustness import TOOL_MARKER
    from ..io.descriptions import shipped_path
    from ..robot.fit import fit_joint_angles
    from ..synthetic.robot import synthesize
    from ..io.urdf import from_urdf

    if robot == "milling_arm":
        chain = from_urdf(shipped_path("milling_arm"), extra_frames=TOOL_MARKER)
        wrist = [chain.joint_index(n) for n in WRIST]
    else:
        from ..io.descriptions import example_robot_urdf
        from .robustness import _depths

        chain = from_urdf(example_robot_urdf(robot))
        order = np.argsort(_depths(chain), kind="stable")
        wrist = [int(j) for j in order[-max(1, chain.n_joints // 3):]]
    rows = []
    for k in range(n_trials or (2 if quick else 8)):
        trial = synthesize(chain, n_frames=n_frames, noise_px=noise_px, seed=100 + k, camera="static")
        for end, frames in (("last", slice(n_frames - hidden_frames, None)), ("first", slice(0, hidden_frames))):
            tracks = trial.tracks.copy()
            tracks[frames, wrist] = np.nan
            for decay in decays:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    fit = fit_joint_angles(trial.positions, chain=chain, tracks=tracks, speed_decay_s=decay)
                worst, error_m = trial_errors(fit, trial)
                silent = [j["name"] for j in judge_joints(fit, trial) if j["verdict"] == "silent"]
                rows.append(dict(trial=k, end=end, decay=decay, worst_deg=worst, error_mm=1000 * error_m,
                                 silent=silent))
                if progress:
                    progress(f"trial {k}, {end} second hidden, speed_decay_s={decay}: worst joint {worst:.2f} deg, "
                             f"{1000 * error_m:.1f} mm")
    return rows


def format_hidden_ends(rows: Sequence[dict]) -> str:
    """Markdown: one line per decay setting; every run in every mean and maximum."""
    lines = ["| speed_decay_s | runs | wrist flipped (> 90 deg) | runs with a silent failure "
             "| worst joint RMS deg (mean) | (max) | 3D error mm (mean) | (max) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for decay in dict.fromkeys(r["decay"] for r in rows):
        sub = [r for r in rows if r["decay"] == decay]
        worst = np.array([r["worst_deg"] for r in sub])
        err = np.array([r["error_mm"] for r in sub])
        flipped = int((worst > FLIPPED_DEG).sum())
        silent = sum(bool(r.get("silent")) for r in sub)
        lines.append(f"| {'none' if decay is None else f'{decay:g} s'} | {len(sub)} | {flipped} | {silent} | "
                     f"{worst.mean():.2f} | {worst.max():.2f} | {err.mean():.1f} | {err.max():.1f} |")
    return "\n".join(lines)
