"""Are the fit's standard deviations honest? (issue 21, part 1)

    python benchmarks/bench_uncertainty.py                     # 50 trials, milling arm, 60 frames, 1 px, static camera
    python benchmarks/bench_uncertainty.py --trials 5 --robot ur10

Each trial films the robot (chainspace.synthesize: a random smooth motion, a static weak-perspective
camera, Gaussian pixel noise), reconstructs, fits the joint angles (defaults: acceleration prior on)
and compares the fitted angles with the truth frame by frame: the share of true values within one
reported standard deviation (``fit.q_std``; target 68 % +- 10 %) and within two (95 % for a
Gaussian), per joint and overall. A joint seen only relative to frame 0 is compared as its change
since frame 0. Every trial counts, a fit on a wrong branch included (its errors lie far outside);
joints flagged ambiguous are counted too and their number is reported. Prints a markdown table.
"""

import argparse
import sys
import time
import warnings

import numpy as np


def run(trials: int, n_frames: int, robot: str, noise_px: float, progress=None, max_minutes: float = float("inf")) -> dict:
    from chainspace.bench.robots import ROBOTS, robot_chain
    from chainspace.io.descriptions import example_robot_urdf
    from chainspace.io.urdf import from_urdf
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.synthetic.robot import synthesize

    chain = robot_chain(robot) if robot in ROBOTS else from_urdf(example_robot_urdf(robot))
    inside1, inside2, err2, std2, n_amb, secs = [], [], [], [], 0, 0.0
    names = None
    start = time.perf_counter()
    for seed in range(trials):
        if time.perf_counter() - start > 60 * max_minutes:
            break  # the time budget: the table says how many trials ran
        trial = synthesize(chain, n_frames=n_frames, noise_px=noise_px, seed=seed, camera="static")
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fit = fit_joint_angles(reconstruct(trial.tracks, chain, seed=seed), fps=trial.fps)
        secs += time.perf_counter() - t0
        robot_k = fit.kinematics()
        names = fit.joint_names
        d = fit.angles - robot_k.angles(trial.q)
        d = np.where(robot_k.turns_v, (d + np.pi) % (2 * np.pi) - np.pi, d)
        rel = np.asarray(fit.relative, bool)
        d[:, rel] = np.where(robot_k.turns_v[rel], (d[:, rel] - d[0, rel] + np.pi) % (2 * np.pi) - np.pi,
                             d[:, rel] - d[0, rel])
        judged = (np.asarray(fit.observable, bool) | rel)[None] & np.isfinite(fit.q_std) & (fit.q_std > 0)
        s = np.where(judged, fit.q_std, np.nan)
        inside1.append(np.where(judged, np.abs(d) <= s, np.nan))
        inside2.append(np.where(judged, np.abs(d) <= 2 * s, np.nan))
        err2.append(np.where(judged, d ** 2, np.nan))
        std2.append(s ** 2)
        n_amb += int(np.asarray(fit.ambiguous, bool).any())
        if progress:
            worst = np.degrees(np.sqrt(np.nanmean(err2[-1], axis=0)))
            flagged = [n for n, a in zip(names, np.asarray(fit.ambiguous, bool)) if a]
            progress(f"trial {seed + 1}/{trials}: within 1 std {np.nanmean(inside1[-1]):.2f}, worst joint "
                     f"{names[int(np.nanargmax(worst))]} {np.nanmax(worst):.1f} deg RMS, ambiguous: "
                     f"{', '.join(flagged) or '-'}, {time.perf_counter() - t0:.1f} s")
    i1, i2 = np.concatenate(inside1), np.concatenate(inside2)
    e, s = np.concatenate(err2), np.concatenate(std2)
    unit = np.where(robot_k.prismatic_v, 1000.0, np.degrees(1.0))
    rows = [dict(joint=n, within1=np.nanmean(i1[:, k]), within2=np.nanmean(i2[:, k]),
                 rms_err=np.sqrt(np.nanmean(e[:, k])) * unit[k], rms_std=np.sqrt(np.nanmean(s[:, k])) * unit[k],
                 unit="mm" if robot_k.prismatic_v[k] else "deg")
            for k, n in enumerate(names) if np.isfinite(i1[:, k]).any()]
    return dict(rows=rows, within1=float(np.nanmean(i1)), within2=float(np.nanmean(i2)), trials=len(inside1),
                n_frames=n_frames, robot=robot, noise_px=noise_px, ambiguous_trials=n_amb, seconds=secs)


def table(res: dict) -> str:
    out = [f"Uncertainty honesty: {res['robot']}, {res['trials']} trials x {res['n_frames']} frames, static camera, "
           f"{res['noise_px']:g} px noise ({res['ambiguous_trials']} trials with a joint flagged ambiguous; "
           f"{res['seconds']:.0f} s of fitting).", "",
           "| joint | within 1 std % (target 68 +- 10) | within 2 std % (95) | RMS error | RMS reported std |",
           "|---|---|---|---|---|"]
    for r in res["rows"]:
        out.append(f"| {r['joint']} | {100 * r['within1']:.1f} | {100 * r['within2']:.1f} | "
                   f"{r['rms_err']:.3f} {r['unit']} | {r['rms_std']:.3f} {r['unit']} |")
    out.append(f"| **all** | **{100 * res['within1']:.1f}** | **{100 * res['within2']:.1f}** | | |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=50)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--robot", default="milling arm", help="a benchmark robot (bench_robots) or an example-robot-data name")
    p.add_argument("--noise", type=float, default=1.0, help="pixel noise per coordinate")
    p.add_argument("--max-minutes", type=float, default=float("inf"),
                   help="stop starting trials after this long (the table counts the trials that ran)")
    p.add_argument("--quick", action="store_true", help="2 trials of the double pendulum, 10 frames (a smoke run)")
    a = p.parse_args(argv)
    if a.quick:
        a.trials, a.frames, a.robot = 2, 10, "double_pendulum"
    if a.trials < 1 or a.frames < 3 or not a.noise > 0:
        p.error("--trials >= 1, --frames >= 3 and --noise > 0 are needed")
    res = run(a.trials, a.frames, a.robot, a.noise, lambda m: print(m, file=sys.stderr, flush=True), a.max_minutes)
    print(table(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
