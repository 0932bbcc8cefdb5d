"""Robot benchmark (issue 4): joint angles from one camera's 2D tracks, against the truth.

    python benchmarks/bench_robots.py            # 6 robots x (0, 1, 3 px static; 1 px per-frame), 300 frames, 3 seeds
    python benchmarks/bench_robots.py --quick    # 60 frames, 1 seed, static 1 px only
    python benchmarks/bench_robots.py --robots "milling arm" UR10 --seeds 1

Prints one markdown table (see chainspace.bench.robots).
"""

import argparse
import sys

from chainspace.bench.robots import CONDITIONS, ROBOT_NAMES, ROBOTS, format_robot_table, run_robot_benchmark


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="60 frames, one seed, static camera at 1 px only")
    p.add_argument("--robots", nargs="+", choices=ROBOT_NAMES, default=None)
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--seeds", type=int, default=None)
    p.add_argument("--static-1px", action="store_true", help="only the target condition (static camera, 1 px)")
    a = p.parse_args(argv)
    conds = [("static", 1.0)] if a.static_1px else (None if a.quick else CONDITIONS)
    rows = run_robot_benchmark(a.quick, lambda m: print(m, file=sys.stderr, flush=True), robots=a.robots,
                               n_frames=a.frames, seeds=a.seeds, conditions=conds)
    print(format_robot_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
