"""Human walks filmed by a static pinhole camera 3-5 m away (see chainspace.bench.reconstruction,
``run_static_benchmark``): straight, turning through a full circle, towards/away; pinhole tracks
with and without intrinsics against the orthographic view of the same motion.

    .venv/bin/python benchmarks/bench_static_camera.py --set tune          # CMU 35_01, 35_02
    .venv/bin/python benchmarks/bench_static_camera.py --set "held out"    # 02_01, 07_01, 16_15, 09 run 1
    .venv/bin/python benchmarks/bench_static_camera.py --set DeepMimic dog # clips as recorded; the dog mocap
    .venv/bin/python benchmarks/bench_static_camera.py --quick             # one sequence per set, 0 px

Columns: the orthographic view of the same motion (KCS stage, default pipeline), the pinhole tracks
without intrinsics (KCS stage, default pipeline) and with them. Sets whose data are missing are
printed as skipped rows.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402

from chainspace.bench.reconstruction import (MOTIONS, STATIC_SETS, format_static_table,  # noqa: E402
                                             run_static_benchmark)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", nargs="*", default=list(STATIC_SETS), choices=list(STATIC_SETS))
    ap.add_argument("--quick", action="store_true", help="one sequence per set, 0 px, straight only")
    ap.add_argument("--sequences", type=int, default=None, help="at most this many sequences per set")
    ap.add_argument("--frames", type=int, default=None, help="at most this many frames per sequence")
    ap.add_argument("--motions", nargs="*", default=list(MOTIONS))
    ap.add_argument("--noise", type=float, nargs="*", default=[0.0, 2.0])
    ap.add_argument("--cameras", type=int, default=1, help="random cameras per sequence and motion")
    args = ap.parse_args(argv)
    motions, noise = (["straight"], [0.0]) if args.quick else (args.motions, args.noise)
    rows = run_static_benchmark(args.set, motions, noise, args.cameras,
                                progress=lambda m: print(m, file=sys.stderr, flush=True),
                                max_sequences=1 if args.quick else args.sequences, max_frames=args.frames)
    print(format_static_table(rows))
    if not any(r["runs"] for r in rows):
        print("skipped: no data for the sets asked (the CMU walks, DeepMimic clips and dog motion capture: set "
              "CHAINSPACE_DATA or place the shared data beside the repo)", file=sys.stderr)
        return 77  # `make bench`: data missing, skipped
    return 0


if __name__ == "__main__":
    sys.exit(main())
