"""Robustness: 3D error against pixel noise (0-10 px) and missing data (0-50 %, random points and whole
limbs hidden for about a second) on the CMU subject-35 walks and the milling arm
(see chainspace.bench.robustness).

    .venv/bin/python benchmarks/bench_robustness.py               # full: every walk x 2 cameras, 4 arm trials
    .venv/bin/python benchmarks/bench_robustness.py --quick       # 3 walks x 1 camera, 1 short arm trial
    .venv/bin/python benchmarks/bench_robustness.py --plots DIR   # also robustness_noise.png, robustness_missing.png

Prints markdown tables and the targets (20 % random missing <= 1.25 x full data; no cliff: no step
between neighbouring levels rising more than 5 mm and either 3 x faster than the sweep's mean slope or
to more than double the error before it; the rule is printed with the tables). Exit code 1 when a
target fails. The walks use ../shared/data when present, else the bundled 35_01 and 35_02.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # tiny matrices: BLAS threads only add overhead

import argparse  # noqa: E402
import sys  # noqa: E402

from chainspace.bench.robustness import (SWEEPS, check_targets, format_robustness, plot_robustness,  # noqa: E402
                                             run_robustness)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a short run (about a minute)")
    ap.add_argument("--datasets", nargs="*", default=["walk35", "milling arm"], help='"walk35" and/or "milling arm"')
    ap.add_argument("--cameras", type=int, default=None, help="camera paths per walk (default 2, quick 1)")
    ap.add_argument("--seeds", type=int, default=None, help="milling-arm trials (default 4, quick 1)")
    ap.add_argument("--frames", type=int, default=None, help="frames per milling-arm trial (default 150, quick 60)")
    ap.add_argument("--trajectory", default="random", choices=["random", "milling"],
                    help="milling-arm motion: smooth random joints or the demo's contour path")
    ap.add_argument("--base-noise", type=float, default=2.0, help="pixel noise under the missing-data sweeps")
    ap.add_argument("--sweeps", nargs="*", default=list(SWEEPS), choices=SWEEPS, help="which sweeps to run")
    ap.add_argument("--no-tool-marker", action="store_true",
                    help="track the milling arm without the mark on its spindle (its tool points then lie in one plane)")
    ap.add_argument("--plots", default=None, metavar="DIR", help="write the two plots into DIR")
    ap.add_argument("--overwrite", action="store_true", help="replace existing plots")
    args = ap.parse_args(argv)
    rows = run_robustness(args.quick, lambda m: print(m, file=sys.stderr), datasets=args.datasets,
                          n_cameras=args.cameras, n_seeds=args.seeds, n_frames=args.frames,
                          base_noise_px=args.base_noise, arm_trajectory=args.trajectory, sweeps=args.sweeps,
                          tool_marker=not args.no_tool_marker)
    if not rows:
        print("skipped: no data (the walks need chainspace's bundled data or ../shared/data)", file=sys.stderr)
        return 77  # `make bench`: data missing, skipped
    print(format_robustness(rows))
    if args.plots:
        for p in plot_robustness(rows, args.plots, overwrite=args.overwrite):
            print(f"wrote {p}", file=sys.stderr)
    return 0 if all(ok for _, ok, _ in check_targets(rows)) else 1


if __name__ == "__main__":
    sys.exit(main())
