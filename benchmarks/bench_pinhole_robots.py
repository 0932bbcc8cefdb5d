"""Robots filmed by a static pinhole camera (issue 17): joint angles from one camera's 2D tracks.

    python benchmarks/bench_pinhole_robots.py                       # 4 robots x 4 conditions, 60 frames, 1 seed
    python benchmarks/bench_pinhole_robots.py --robots "milling arm" --frames 30 --seeds 2
    python benchmarks/bench_pinhole_robots.py --conditions K focal --json p.json   # each run saved as it comes;
                                                                    # run again to resume
    python benchmarks/bench_pinhole_robots.py --from-json p.json    # the table of the saved runs
    python benchmarks/bench_pinhole_robots.py --quick                # milling arm, K, 20 frames

Conditions (1 px noise, 1920x1080 images, one static pinhole camera 1.5-3 reaches from the centre of the
robot's working volume unless said otherwise; the tracks are reconstructed with chainspace.reconstruct,
then fitted with fit_joint_angles):

* ``K``: intrinsics known (focal 0.8-1.2 x the width, drawn by seed).
* ``focal``: focal unknown, ``image_size`` given (estimated; error in %).
* ``close``: intrinsics known, a 90-degree lens (f = w / 2) moved in until the robot's nearest tracked
  point over the sequence is 0.3 m from it (points may leave the image; they are kept).
* ``distortion``: intrinsics known with lens distortion (k1, k2, p1, p2, k3) = (-0.25, 0.08, 0.001, -0.001, 0).

Per row: runs, failed runs (an exception: counted in the error columns as infinite, and in its own), the
worst judged joint's RMS (deg, mean and max over runs; the joint named), the judged joints (observable or
seen relative to frame 0, and not flagged) and the flagged ones (the fit reports them ambiguous: a tie, a
poor fit or an uncertain joint; listed with their error, not judged), the 3D error (% of reach), focal error (%, with the
fit's reported std), the share of the judged joints' frames whose error lies within one reported
standard deviation (``fit.q_std``; honest: about 68 %), seconds and frames/s. The progress lines on
stderr give each joint's RMS error beside the RMS of its reported std.
Targets: K <= 1 deg; focal unknown <= 2 deg and focal within 2 %; close range <= 2 deg.
"""

import argparse
import json
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

from chainspace.bench.robots import ROBOT_NAMES, ROBOTS, robot_chain, trial_errors

CONDITIONS = ["K", "focal", "close", "distortion"]
DIST = (-0.25, 0.08, 0.001, -0.001, 0.0)


def film(chain, robot, cond, n_frames, seed):
    from chainspace.synthetic.robot import synthesize

    kw = dict(n_frames=n_frames, noise_px=1.0, seed=seed, camera="phone")  # distortion only where the row says
    if cond == "distortion":
        kw["dist"] = DIST
    if cond != "close":
        return synthesize(chain, **kw)
    kw["focal_px"] = 960.0  # 90 degrees across 1920 px
    d = 1.0
    for _ in range(4):  # move in until the nearest point is 0.3 m away (same seed: same motion and azimuth)
        tr = synthesize(chain, distance_reaches=d, **kw)
        near = float((tr.positions @ tr.camera_R.T + tr.camera_t)[..., 2].min())
        d = max(d - (near - 0.3) / robot.reach(), 0.05)
    return synthesize(chain, distance_reaches=d, **kw)


def _reason_kinds(reason: str) -> str:
    """The kinds of a flagged joint's reasons ("tie", "poor fit", "uncertain"), from validate's reason
    ("kind: why; kind: why")."""
    kinds = [part.split(":")[0].strip() for part in reason.split("; ") if ":" in part]
    return ", ".join(dict.fromkeys(kinds)) or "tie"


def joint_report(fit, tr):
    """Per degree of freedom (validate's rows): name, status, judged, RMS and largest error (deg or mm), the RMS over
    frames of its reported std and the share of its frames within one std (None without q_std), and
    for a flagged joint what flagged it (a tie, a poor fit, an uncertain joint)."""
    from chainspace.robot.validation import validate

    std = None if fit.q_std is None else np.asarray(fit.q_std, float)
    out = []
    for k, j in enumerate(validate(fit, tr.q).joints):
        scale = np.degrees(1.0) if j["unit"] == "deg" else 1000.0
        s = None if std is None or not np.isfinite(std[:, k]).any() else float(scale * np.sqrt(np.nanmean(std[:, k] ** 2)))
        out.append(dict(name=j["name"], status=j["status"], judged=bool(j["judged"]), unit=j["unit"], rms=j["rms"],
                        max=j["max"], std_rms=s, within=j.get("within_1_std_pct"),
                        reason=_reason_kinds(j.get("reason") or "") if j["status"] == "ambiguous" else None))
    return out


def one_run(name, chain, robot, cond, n_frames, seed):
    """One film-reconstruct-fit run as a JSON-able dict (``error`` holds the exception of a failed run)."""
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles

    run = dict(robot=name, cond=cond, seed=seed, frames=n_frames, error=None)
    try:
        tr = film(chain, robot, cond, n_frames, seed)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = reconstruct(tr.tracks, chain, seed=seed)
            kw = dict(image_size=tr.image_size) if cond == "focal" else dict(intrinsics=tr.intrinsics)
            fit = fit_joint_angles(rec, tracks=tr.tracks, **kw)
        run["secs"] = time.perf_counter() - t0
        worst, e3 = trial_errors(fit, tr)
        joints = joint_report(fit, tr)
        deg = [j for j in joints if j["judged"] and j["unit"] == "deg" and j["rms"] is not None]
        within = [j["within"] for j in joints if j["judged"] and j["within"] is not None]
        f_true = float(tr.intrinsics.K[0, 0])
        run.update(worst_deg=worst, worst_joint=max(deg, key=lambda j: j["rms"])["name"] if deg else None,
                   e3_pct=100 * e3 / robot.reach(), joints=joints, message=fit.message,
                   within_pct=float(np.mean(within)) if within else None,  # same frames per joint: the pooled share
                   focal_err_pct=None if cond != "focal" or fit.focal_px is None
                   else 100 * abs(fit.focal_px - f_true) / f_true,
                   focal_std_pct=None if cond != "focal" or fit.focal_std_px is None
                   else 100 * fit.focal_std_px / f_true)
    except Exception as ex:
        run["error"] = f"{type(ex).__name__}: {ex}"
        run["traceback"] = traceback.format_exc()
    return run


def describe(run):
    """One progress line per run (the table's cells and each joint's error beside its reported std)."""
    if run["error"]:
        return f"{run['robot']} {run['cond']} seed {run['seed']}: FAILED\n{run['traceback']}"
    js = ", ".join(f"{j['name']} {j['rms']:.2f} (max {j.get('max', float('nan')):.1f})" + (f" (std {j['std_rms']:.2f}, {j['within']:.0f} % within)"
                                                      if j["std_rms"] is not None and j["within"] is not None else "")
                   + ("" if j["judged"] else f" [{j['status']}{', ' + j['reason'] if j['reason'] else ''}]")
                   for j in run["joints"] if j["rms"] is not None)
    return (f"{run['robot']} {run['cond']} seed {run['seed']}: worst joint {run['worst_deg']:.3f} deg "
            f"({run['worst_joint']}), 3D {run['e3_pct']:.2f} %, {run['secs']:.0f} s; {run['message'][-160:]}\n  " + js)


def run_all(robots, conds, n_frames, seeds, progress, runs=(), on_run=None):
    """Every (robot, condition, seed) not already in ``runs`` (a resumed file's, same frame count); each
    new run is handed to ``on_run(all runs so far)`` as it ends. Returns every run."""
    from chainspace.robot.kinematics import RobotKinematics

    runs = list(runs)
    done = {(r["robot"], r["cond"], r["seed"], r["frames"]) for r in runs}
    for name in robots:
        todo = [(c, s) for c in conds for s in range(seeds) if (name, c, s, n_frames) not in done]
        if not todo:
            continue
        try:
            chain = robot_chain(name)
        except Exception as e:  # e.g. example-robot-data without this robot
            runs.append(dict(robot=name, cond="-", seed=0, frames=n_frames, error=f"skipped: {type(e).__name__}: {e}"))
            continue
        robot = RobotKinematics(chain.metadata["urdf_path"], chain)
        for cond, seed in todo:
            runs.append(one_run(name, chain, robot, cond, n_frames, seed))
            progress(describe(runs[-1]))
            if on_run:
                on_run(runs)
    return runs


def _cell(v, fmt):
    if not v:
        return "-"
    return (fmt + " / " + fmt).format(float(np.mean(v)), float(np.max(v))) if len(v) > 1 else fmt.format(v[0])


def table(runs):
    """The runs as one markdown table, one row per robot, condition and frame count (most frames first,
    then the robots' and conditions' order; cells: mean / max over runs when there are several)."""
    rows = {}
    order = {n: k for k, n in enumerate(ROBOT_NAMES)}
    for r in sorted(runs, key=lambda r: (-r["frames"], order.get(r["robot"], len(order)),
                                         CONDITIONS.index(r["cond"]) if r["cond"] in CONDITIONS else -1)):
        rows.setdefault((r["robot"], r["cond"], r["frames"]), []).append(r)
    out = ["1 px noise, static pinhole camera. Cells: mean / max over runs (a failed run counts as infinite).", "",
           "| robot | condition | frames | runs | failed | worst judged joint RMS (deg) | judged joints | flagged (not judged: RMS deg) "
           "| 3D error (% reach) | focal error (%) | within 1 std (%) | seconds | frames/s |",
           "|---|---|---:|---:|---:|---:|---|---|---:|---:|---:|---:|---:|"]
    for (robot, cond, frames), rs in rows.items():
        ok = [r for r in rs if not r["error"]]
        fail = len(rs) - len(ok)
        worst = [r["worst_deg"] for r in ok] + [np.inf] * fail
        e3 = [r["e3_pct"] for r in ok] + [np.inf] * fail
        wname = max(ok, key=lambda r: r["worst_deg"])["worst_joint"] if ok else None
        judged = sorted({j["name"] for r in ok for j in r["joints"] if j["judged"]},
                        key=lambda n: [j["name"] for j in ok[0]["joints"]].index(n))
        flagged = {}
        for r in ok:
            for j in r["joints"]:
                if j["status"] == "ambiguous":
                    flagged.setdefault(j["name"], []).append((j["rms"], j["reason"]))
        fl = ", ".join(f"{n} {max(x for x, _ in v):.2f} ({'/'.join(sorted({w for _, w in v}))})"
                       for n, v in flagged.items()) or "-"
        focal = [r["focal_err_pct"] for r in ok if r.get("focal_err_pct") is not None]
        fstd = [r["focal_std_pct"] for r in ok if r.get("focal_std_pct") is not None]
        within = [r["within_pct"] for r in ok if r.get("within_pct") is not None]
        secs = sum(r["secs"] for r in ok)
        out.append(f"| {robot} | {cond} | {frames} | {len(rs)} | {fail} | "
                   f"{_cell(worst, '{:.3f}')}{f' ({wname})' if wname else ''} | "
                   f"{len(judged)} of {len(ok[0]['joints']) if ok else '-'}: {', '.join(judged) or '-'} | "
                   f"{fl} | {_cell(e3, '{:.2f}')} | {_cell(focal, '{:.3f}')}"
                   f"{f' (std {np.mean(fstd):.2f})' if fstd else ''} | {_cell(within, '{:.0f}')} | {secs:.0f} | "
                   f"{len(ok) * frames / secs if secs else float('nan'):.2f} |")
    fails = [f"- {r['robot']} {r['cond']} seed {r['seed']}: {r['error']}" for r in runs if r["error"]]
    return "\n".join(out + ([""] + ["Failed runs:"] + fails if fails else []))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", nargs="+", choices=ROBOT_NAMES, default=list(ROBOTS))
    p.add_argument("--conditions", nargs="+", choices=CONDITIONS, default=CONDITIONS)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--quick", action="store_true", help="milling arm, intrinsics known, 20 frames")
    p.add_argument("--json", default=None, help="save every run here as it comes; runs already in it are not run "
                                                 "again (resume); the table shows every run in the file")
    p.add_argument("--from-json", nargs="+", default=None, help="print the table of runs saved with --json")
    a = p.parse_args(argv)
    if a.quick:
        a.robots, a.conditions, a.frames = ["milling arm"], ["K"], 20
    if a.from_json:
        print(table([r for f in a.from_json for r in json.loads(Path(f).read_text())]))
        return 0
    path = Path(a.json) if a.json else None
    runs = json.loads(path.read_text()) if path and path.exists() else []
    if not isinstance(runs, list) or any(not isinstance(r, dict) or "cond" not in r for r in runs):
        p.error(f"{path} is no file of this benchmark")

    def save(runs):
        from chainspace.io.results import atomic_write

        with atomic_write(path, overwrite=True) as fh:  # our own file (checked above), rewritten with each run
            fh.write(json.dumps(runs, indent=1, default=float))

    runs = run_all(a.robots, a.conditions, a.frames, a.seeds, lambda m: print(m, file=sys.stderr, flush=True),
                   runs=runs, on_run=save if path else None)
    print(table(runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
