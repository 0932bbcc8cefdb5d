"""Frames per second of the KCS stage and of the default pipeline, 1,000 to 100,000 frames, with one
BLAS thread and with all cores, and the peak memory per frame.

    .venv/bin/python benchmarks/bench_speed.py            # 1,000, 10,000 and 100,000 frames
    .venv/bin/python benchmarks/bench_speed.py --quick    # up to 10,000 frames

A 17-joint human17 chain moving smoothly (chainspace.synthetic.views.swing_motion at 120 Hz), a
low-motion orbit camera, 2 px noise (chainspace.bench.reconstruction.run_speed). Prints a markdown
table (frames/s on the wall clock and per CPU second, the KCS iterations and refinement sweeps, the
peak memory per frame) and the linearity of each stage (frames/s at the largest size over the
smallest; 1 = cost linear in frames). On a shared machine compare the per-CPU-second columns. Each size is repeated for about a second and the fastest run counts (the machine
may be shared). The thread count is set per call (reconstruct(..., blas_threads=1 or None), through
threadpoolctl); peak memory is tracemalloc's, in a separate run.
"""

from __future__ import annotations

import argparse
import sys

from chainspace.bench.reconstruction import format_speed, run_speed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="stop at 10,000 frames")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1_000, 10_000, 100_000], help="numbers of frames")
    args = ap.parse_args(argv)
    rows = run_speed(args.sizes, quick=args.quick, progress=lambda m: print(m, file=sys.stderr))
    print(format_speed(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
