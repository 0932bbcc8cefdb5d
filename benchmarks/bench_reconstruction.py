"""The paper's Table 1 protocol on CMU and DeepMimic sequences (see chainspace.bench.reconstruction).

    .venv/bin/python benchmarks/bench_reconstruction.py            # full: 20 cameras per sequence
    .venv/bin/python benchmarks/bench_reconstruction.py --quick    # 3 sequences x 3 cameras per group

Needs ../shared/data (or $CHAINSPACE_DATA). Prints one markdown table.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: BLAS threads only add overhead

import argparse  # noqa: E402
import sys

from chainspace.bench.reconstruction import format_table, run_benchmark


SKIPPED = 77  # the exit code `make bench` reads as "data missing, skipped" (as automake's test harness does)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="3 sequences x 3 camera paths per group")
    ap.add_argument("--cameras", type=int, default=None, help="camera paths per sequence (default 20, quick 3)")
    ap.add_argument("--groups", nargs="*", default=None, help="e.g. walk35 run09")
    ap.add_argument("--noise", type=float, nargs="*", default=[0.0, 2.0, 5.0], help="pixel noise levels")
    ap.add_argument("--robots", action="store_true", help="append the robot rows of chainspace.bench.robots")
    args = ap.parse_args(argv)
    extra = []
    if args.robots:
        try:
            from chainspace import benchmark_robots  # H4's module: rows(noise_levels, quick) -> list[Row]
            extra.append(benchmark_robots.rows)
        except (ImportError, AttributeError) as exc:
            print(f"robot rows unavailable: {exc}", file=sys.stderr)
    n_cam = args.cameras or (3 if args.quick else 20)
    rows = run_benchmark(args.groups, noise_levels=args.noise, n_cameras=n_cam, quick=args.quick, extra=extra,
                         progress=lambda m: print(m, file=sys.stderr))
    if not rows:
        print("skipped: no benchmark data found (the CMU and DeepMimic sequences): set CHAINSPACE_DATA or place "
              "the shared data beside the repo", file=sys.stderr)
        return SKIPPED
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
