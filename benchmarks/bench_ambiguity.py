"""Does the fit say when it does not know? (issue 21, part 2) Legs and limbs that hang below their base.

    python benchmarks/bench_ambiguity.py                 # Solo12's front-left leg, TALOS's left arm; 3 seeds x 30 frames
    python benchmarks/bench_ambiguity.py --seeds 1 --robots "quadruped leg"

Each trial films the robot (chainspace.synthesize: random smooth motion of every joint within its
limits, a static weak-perspective camera 10-35 degrees above the base plane, 1 px noise),
reconstructs and fits (defaults). Per joint the fit either gets it within 2 degrees RMS, or flags it
(ambiguous, not observable), or fails silently (off by more and not flagged: the bug this guards
against). Both robots hang below their base, where the camera-side rule does not apply (their mirror
ties are left unsettled and reported). Needs example-robot-data. Prints a markdown table.
"""

import argparse
import sys
import time
import warnings

ROWS = {
    # one leg of a quadruped, fitted as a fixed-base sub-chain (the trunk held still): the other legs'
    # joints move no tracked point and are reported not observable
    "quadruped leg": ("solo12", ["base_link", "FL_SHOULDER", "FL_UPPER_LEG", "FL_LOWER_LEG", "FL_FOOT"]),
    "humanoid arm": ("talos_arm", None),  # TALOS's left arm from its shoulder (example-robot-data's URDF)
}
LIMIT_DEG = 2.0


def run(robots, seeds: int, n_frames: int, progress=None, search_ties: bool = True) -> list[dict]:
    from chainspace.io.descriptions import example_robot_urdf
    from chainspace.io.urdf import from_urdf
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.robot.validation import validate
    from chainspace.synthetic.robot import synthesize

    rows = []
    for name in robots:
        urdf, links = ROWS[name]
        chain = from_urdf(example_robot_urdf(urdf), links=links)
        good = flagged = silent = 0
        worst_silent, secs, flagged_names, silent_rows = 0.0, 0.0, set(), []
        for seed in range(seeds):
            trial = synthesize(chain, n_frames=n_frames, noise_px=1.0, seed=seed, camera="static")
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fit = fit_joint_angles(reconstruct(trial.tracks, chain, seed=seed), fps=trial.fps,
                                       search_ties=search_ties)
            secs += time.perf_counter() - t0
            for j in validate(fit, trial.q).joints:
                if j["status"] in ("observable", "relative to frame 0"):
                    if j["rms"] <= LIMIT_DEG:
                        good += 1
                    else:
                        silent += 1
                        worst_silent = max(worst_silent, j["rms"])
                        silent_rows.append(f"{j['name']} {j['rms']:.1f} deg (std {j.get('std_median') or float('nan'):.1f})")
                elif j["status"] == "ambiguous":
                    flagged += 1
                    flagged_names.add(j["name"])
            if progress:
                progress(f"{name} seed {seed}: {time.perf_counter() - t0:.0f} s; {fit.message[:160]}")
        rows.append(dict(robot=name, urdf=urdf, seeds=seeds, n_frames=n_frames, good=good, flagged=flagged,
                         silent=silent, worst_silent_deg=worst_silent, flagged_names=sorted(flagged_names),
                         silent_rows=silent_rows,
                         seconds=secs))
    return rows


def table(rows: list[dict]) -> str:
    out = [f"| robot | trials | joints within {LIMIT_DEG:g} deg RMS | flagged ambiguous | silent failures "
           "(worst) | flagged joints | silent: error (reported median std) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['robot']} ({r['urdf']}) | {r['seeds']} x {r['n_frames']} frames | {r['good']} | "
                   f"{r['flagged']} | {r['silent']} ({r['worst_silent_deg']:.1f} deg) | "
                   f"{', '.join(r['flagged_names']) or '-'} | {'; '.join(r['silent_rows']) or '-'} |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", nargs="+", choices=list(ROWS), default=list(ROWS))
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--quick", action="store_true", help="the quadruped leg, one seed, 10 frames (a smoke run)")
    p.add_argument("--no-search-ties", dest="search_ties", action="store_false",
                   help="fit_joint_angles(search_ties=False): only the fit's own candidates (faster)")
    a = p.parse_args(argv)
    if a.quick:
        a.robots, a.seeds, a.frames = ["quadruped leg"], 1, 10
    if a.seeds < 1 or a.frames < 3:
        p.error("--seeds >= 1 and --frames >= 3 are needed")
    try:
        rows = run(a.robots, a.seeds, a.frames, lambda m: print(m, file=sys.stderr, flush=True), a.search_ties)
    except Exception as exc:  # example-robot-data missing: say so, exit non-zero (no empty table)
        from chainspace.errors import ChainspaceError, DescriptionNotFoundError

        if isinstance(exc, DescriptionNotFoundError):
            print(f"bench_ambiguity: skipped: {exc}", file=sys.stderr)
            return 77  # `make bench`: data missing, skipped
        if isinstance(exc, ChainspaceError):
            print(f"bench_ambiguity: {exc}", file=sys.stderr)
            return 2
        raise
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
