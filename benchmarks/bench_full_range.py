"""No silent failure (issue 21): robots over their full joint ranges, cameras above and below the base.

    python benchmarks/bench_full_range.py                          # 16 robots x (above, below), 60 frames
    python benchmarks/bench_full_range.py --robots ur10 panda --frames 30
    python benchmarks/bench_full_range.py --settings "singular, above" --camera static
    python benchmarks/bench_full_range.py --camera static --frames 30 --first-seed 28 --seeds 2  # held-out seeds
    python benchmarks/bench_full_range.py --quick                  # 2 robots x 1 setting, 20 frames
    python benchmarks/bench_full_range.py --no-search-ties         # the fit without its search for ties
    python benchmarks/bench_full_range.py --compare old.json new.json  # two builds' runs (--json) compared

Prints one markdown table, then every silent failure, every flagged joint with its reason and every run
that returned no fit (see chainspace.bench.full_range). Exit code 1 when a robot misses the target
(every joint within 2 degrees RMS or flagged, no crash).
"""

import argparse
import json
import sys
from pathlib import Path

from chainspace.bench.full_range import (DEFAULT_SETTINGS, ROBOTS, SETTINGS, compare_full_range, format_full_range,
                                         run_full_range, summarise)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", nargs="+", default=None, help=f"default: {' '.join(ROBOTS)}")
    p.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=None)
    p.add_argument("--camera", default=None, choices=["pinhole", "phone", "industrial", "static"],
                   help="pinhole (default: a phone or an industrial camera, intrinsics given to the fit) or "
                        "static (weak perspective)")
    p.add_argument("--frames", type=int, default=None, help="frames per run (default 60; --quick 20)")
    p.add_argument("--seeds", type=int, default=1, help="runs per robot and setting (default 1)")
    p.add_argument("--first-seed", type=int, default=0, help="the first run's seed (default 0)")
    p.add_argument("--no-search-ties", dest="search_ties", action="store_false",
                   help="fit_joint_angles(search_ties=False): only the fit's own candidates (faster)")
    p.add_argument("--quick", action="store_true", help="milling arm and UR5, full range from above, 20 frames")
    p.add_argument("--json", default=None, help="also write every run to this JSON file (refuses to overwrite)")
    p.add_argument("--from-json", nargs="+", default=None, help="print the table of runs saved with --json")
    p.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"), default=None,
                   help="compare two files saved with --json (two builds, same runs): counts and changed runs")
    a = p.parse_args(argv)

    def saved(option: str, f: str) -> list:  # the runs of a file written by --json, or a clear error
        try:
            runs = json.loads(Path(f).read_text())
        except (OSError, ValueError) as exc:
            p.error(f"{option}: cannot read {f}: {exc}")
        keys = ("robot", "setting", "seed", "outcome", "joints")
        if not isinstance(runs, list) or not all(isinstance(r, dict) and all(k in r for k in keys) for r in runs):
            p.error(f"{option}: {f} is not a list of runs as --json writes them (each with {', '.join(keys)})")
        return runs

    if a.compare:
        print(compare_full_range(*(saved("--compare", f) for f in a.compare)))
        return 0
    robots = a.robots or (["milling_arm", "ur5"] if a.quick else list(ROBOTS))
    settings = a.settings or (["full, above"] if a.quick else list(DEFAULT_SETTINGS))
    frames = a.frames or (20 if a.quick else 60)
    def save(runs, first=[True]):  # every run as it comes: a long table survives an interruption
        from chainspace.io.results import atomic_write

        with atomic_write(Path(a.json), overwrite=not first[0]) as fh:
            fh.write(json.dumps(runs, indent=1, default=float))
        first[0] = False

    # saved runs record neither their camera nor their frame count: the table names them as given
    camera = a.camera or ("not recorded (give --camera)" if a.from_json else "pinhole")
    if a.from_json:
        runs, frames = [r for f in a.from_json for r in saved("--from-json", f)], a.frames
    else:
        runs = run_full_range(robots, settings, camera=camera, n_frames=frames, seeds=a.seeds,
                              first_seed=a.first_seed,
                              search_ties=a.search_ties,
                              progress=lambda m: print(m, file=sys.stderr, flush=True),
                              on_run=save if a.json else None)
    print(format_full_range(runs, camera=camera, n_frames=frames))
    return 0 if all(r["verdict"].startswith("met") for r in summarise(runs)) else 1


if __name__ == "__main__":
    sys.exit(main())
