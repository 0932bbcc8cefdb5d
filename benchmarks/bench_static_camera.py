"""Human walks filmed by a static pinhole camera 3-5 m away (see chainspace.bench.reconstruction,
``run_static_benchmark``): straight, turning through a full circle, towards/away; pinhole tracks
with and without intrinsics against the orthographic view of the same motion.

    .venv/bin/python benchmarks/bench_static_camera.py --set tune          # CMU 35_01, 35_02
    .venv/bin/python benchmarks/bench_static_camera.py --set "held out"    # 02_01, 07_01, 16_15, 09 run 1
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402

from chainspace.bench.reconstruction import MOTIONS, format_static_table, run_static_benchmark  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", nargs="*", default=["tune", "held out"], help="tune and/or 'held out'")
    ap.add_argument("--motions", nargs="*", default=list(MOTIONS))
    ap.add_argument("--noise", type=float, nargs="*", default=[0.0, 2.0])
    ap.add_argument("--cameras", type=int, default=1, help="random cameras per sequence and motion")
    args = ap.parse_args(argv)
    rows = run_static_benchmark(args.set, args.motions, args.noise, args.cameras,
                                progress=lambda m: print(m, file=sys.stderr, flush=True))
    print(format_static_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
