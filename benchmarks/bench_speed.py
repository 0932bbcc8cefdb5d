"""Frames per second of the KCS stage and of the default pipeline, 100 to 100,000 frames.

    .venv/bin/python benchmarks/bench_speed.py            # 100 .. 100,000 frames
    .venv/bin/python benchmarks/bench_speed.py --quick    # up to 10,000 frames

A 17-joint human17 chain moving smoothly (chainspace.synthetic.views.swing_motion at 120 Hz), a low-motion
orbit camera, 2 px noise (chainspace.bench.reconstruction.run_speed). Prints a markdown table; frames/s that
stay flat show cost linear in frames. Each size is repeated for about a second and the fastest run
counts (the machine may be shared).

chainspace.reconstruct limits BLAS to one thread itself when threadpoolctl is installed; this script
also sets OPENBLAS_NUM_THREADS=1 (unless already set) so that the numbers hold without it.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # thin matrices: BLAS threads only add overhead

import argparse  # noqa: E402
import sys  # noqa: E402

from chainspace.bench.reconstruction import format_speed, run_speed  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="stop at 10,000 frames")
    args = ap.parse_args(argv)
    print(format_speed(run_speed(quick=args.quick, progress=lambda m: print(m, file=sys.stderr))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
