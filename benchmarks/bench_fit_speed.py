"""Speed of the robot fit (issue 19): frames per second of fit_joint_angles, with its accuracy and stages.

    python benchmarks/bench_fit_speed.py                       # UR10, Panda, xArm7; 300 frames; static camera, 1 px
    python benchmarks/bench_fit_speed.py --robots UR10 --frames 100
    python benchmarks/bench_fit_speed.py --robots UR10 --frames 100 --pinhole  # a pinhole camera, K known
    python benchmarks/bench_fit_speed.py --robots UR10 --pinhole --unknown     # ... fitted with perspective=True
    python benchmarks/bench_fit_speed.py --threads 1                           # the compiled solver on one thread
    python benchmarks/bench_fit_speed.py --no-search-ties                      # the fit without its search for ties

Per robot: one synthetic trial (chainspace.synthesize, seed 0), reconstructed from its tracks, then
fit_joint_angles timed alone (the reconstruction is not counted). Frames per second are given on the
wall clock and on the process's CPU time (on a shared machine the wall clock also counts the other
processes' turns; with more than one thread (--threads) the CPU time also counts every thread's);
targets (issue 19): >= 30 frames/s for the 6-axis arm, >= 10 for the 7-axis arms.
Accuracy as in benchmarks/bench_robots.py: the worst judged joint's RMS (degrees) and the fitted
robot's mean 3D error (mm). Stages (seconds, wall): the 3D fit, the refinement of the candidate motions
on the tracks, the smoothed choice among them, and the sequence-wide branch search (Viterbi passes on
the tracks) that runs inside both; then the assessment (standard deviations, and the search for other
motions that fit as well unless --no-search-ties).

Prints one markdown table.
"""

import argparse
import os
import sys
import time
import warnings

TARGET = {"UR10": 30.0, "milling arm": 30.0, "Panda": 10.0, "xArm7": 10.0}


def run(name: str, n_frames: int, noise: float, seed: int, pinhole: bool = False, unknown: bool = False,
        search_ties: bool = True) -> dict:
    from chainspace.bench.robots import robot_chain, trial_errors
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.synthetic.robot import synthesize

    chain = robot_chain(name)
    # pinhole: synthesize's default camera (a real lens at its distance), fitted with its intrinsics
    camera = {} if pinhole else {"camera": "static"}
    trial = synthesize(chain, n_frames=n_frames, noise_px=noise, seed=seed, **camera)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(trial.tracks, chain, seed=seed)
        t0, c0 = time.perf_counter(), time.process_time()
        camera = {"perspective": True} if unknown else {"intrinsics": trial.intrinsics if pinhole else None}
        fit = fit_joint_angles(rec, camera="static", search_ties=search_ties, **camera)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    joint, e3 = trial_errors(fit, trial)
    return dict(robot=name, nv=len(fit.joint_names), frames=n_frames, wall=wall, cpu=cpu, joint=joint,
                mm=1000 * e3, **{k: fit.timings.get(k, float("nan")) for k in
                                 ("fit_3d", "refine_candidates", "smoothed_choice", "branch_search", "uncertainty")})


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", nargs="+", default=["UR10", "Panda", "xArm7"])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--noise", type=float, default=1.0, help="pixel noise (default 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pinhole", action="store_true",
                   help="a pinhole camera (synthesize's default), fitted with its intrinsics known")
    p.add_argument("--unknown", action="store_true",
                   help="fit with perspective=True (focal length and principal point unknown) instead")
    p.add_argument("--threads", type=int, default=None,
                   help="threads of the compiled solver (sets CHAINSPACE_THREADS; default: the usable cores)")
    p.add_argument("--no-search-ties", dest="search_ties", action="store_false",
                   help="fit_joint_angles(search_ties=False): without the search for ties (the default runs it)")
    p.add_argument("--quick", action="store_true", help="the milling arm on 30 frames (a smoke run)")
    a = p.parse_args(argv)
    if a.threads is not None:
        if a.threads < 1:
            p.error(f"--threads must be a positive number, not {a.threads}")
        os.environ["CHAINSPACE_THREADS"] = str(a.threads)
    if a.quick:
        a.robots, a.frames = ["milling arm"], 30
    from chainspace.robot.compiled import compile_now, threads

    compile_now()  # the compiled solver's one-off compilation after an install is not a fit's time
    rows = []
    for name in a.robots:
        r = run(name, a.frames, a.noise, a.seed, a.pinhole, a.unknown, a.search_ties)
        print(f"{name}: {r['frames'] / r['wall']:.2f} frames/s wall, {r['frames'] / r['cpu']:.2f} CPU", file=sys.stderr,
              flush=True)
        rows.append(r)
    print("| robot | joints | frames | frames/s (wall) | frames/s (CPU) | target | worst joint RMS deg | 3D error mm "
          "| 3D fit s | refine candidates s | smoothed choice s | of which branch search s | assessment s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        target = TARGET.get(r["robot"])
        met = "-" if target is None else f">= {target:g} ({'met' if r['frames'] / r['wall'] >= target else 'missed'})"
        fps, fps_cpu = r["frames"] / r["wall"], r["frames"] / r["cpu"]
        print(f"| {r['robot']} | {r['nv']} | {r['frames']} | {fps:.2f} | {fps_cpu:.2f} | {met} | {r['joint']:.3f} | {r['mm']:.2f} | {r['fit_3d']:.1f} | {r['refine_candidates']:.1f} "
              f"| {r['smoothed_choice']:.1f} | {r['branch_search']:.1f} | {r['uncertainty']:.1f} |")
    camera = ("static pinhole camera" if a.pinhole else "static weak-perspective camera") + (
        ", fitted with perspective=True (focal and principal point unknown)" if a.unknown else
        ", intrinsics known" if a.pinhole else "")
    search = "with" if a.search_ties else "without"
    print(f"\n{camera}, {a.noise:g} px noise, seed {a.seed}; fit_joint_angles alone (reconstruction not counted), "
          f"{search} its search for ties (assessment: standard deviations and alternatives); "
          f"stages in wall-clock seconds; compiled solver on {threads()} thread(s).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
