"""Frames per second of the KCS stage and of the default pipeline, 100 to 100,000 frames.

    .venv/bin/python benchmarks/bench_speed.py            # 100 .. 100,000 frames
    .venv/bin/python benchmarks/bench_speed.py --max 10000

A 17-joint human17 chain moving smoothly (chainspace.synthetic.swing_motion at 120 Hz), a low-motion
orbit camera, 2 px noise. Prints a markdown table; frames/s that stay flat show linear cost.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np

from chainspace.datasets import human17
from chainspace.reconstruct import reconstruct
from chainspace.synthetic import observe, orbit_cameras, scale_for_span, swing_motion


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--max", type=int, default=100_000, help="largest number of frames")
    args = ap.parse_args(argv)
    chain = human17()
    sizes = [n for n in (100, 1_000, 10_000, 100_000) if n <= args.max]
    print("| frames | KCS s | KCS frames/s | default s | default frames/s | refine share |")
    print("|---:|---:|---:|---:|---:|---:|")
    for n in sizes:
        X = swing_motion(chain, n, fps=120.0, seed=0)
        P = orbit_cameras(n, scale=scale_for_span(X, 720.0), seed=0)
        W = observe(X, P, translations=[450.0, 450.0], noise_px=2.0, seed=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            reconstruct(W, chain, method="kcs")
            t_kcs = time.perf_counter() - t0
            t0 = time.perf_counter()
            rec = reconstruct(W, chain)
            t_def = time.perf_counter() - t0
        share = rec.timings.get("refine", 0.0) / max(sum(rec.timings.values()), 1e-12)
        print(f"| {n:,} | {t_kcs:.2f} | {n / t_kcs:,.0f} | {t_def:.2f} | {n / t_def:,.0f} | {share:.0%} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
