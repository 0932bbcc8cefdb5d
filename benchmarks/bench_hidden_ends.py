"""Joints hidden at the start or the end of a sequence: the fit's speed decay against none.

    python benchmarks/bench_hidden_ends.py            # 8 trials x (first, last second hidden) x 2 settings
    python benchmarks/bench_hidden_ends.py --quick    # 2 trials

Prints one markdown table (see chainspace.bench.hidden_ends).
"""

import argparse
import sys

from chainspace.bench.hidden_ends import DECAYS, format_hidden_ends, run_hidden_ends


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="2 trials")
    p.add_argument("--trials", type=int, default=None, help="trials (default 8)")
    p.add_argument("--frames", type=int, default=90, help="frames per trial; the first or last third hidden")
    p.add_argument("--decays", nargs="+", default=None, help="speed_decay_s settings, seconds or 'none' "
                   "(default: none 0.5)")
    p.add_argument("--robot", default="milling_arm", help="milling_arm (default) or an example-robot-data name")
    a = p.parse_args(argv)
    decays = DECAYS if a.decays is None else tuple(None if d == "none" else float(d) for d in a.decays)
    rows = run_hidden_ends(a.quick, lambda m: print(m, file=sys.stderr, flush=True), n_trials=a.trials,
                           decays=decays, n_frames=a.frames, hidden_frames=a.frames // 3, robot=a.robot)
    print(format_hidden_ends(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
