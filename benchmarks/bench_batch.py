"""A batch of 40 small recordings on the local Dask cluster against one recording alone.

    .venv/bin/python benchmarks/bench_batch.py                 # 40 recordings x 300 frames, one worker per core
    .venv/bin/python benchmarks/bench_batch.py --recordings 8 --frames 200 --workers 2
    .venv/bin/python benchmarks/bench_batch.py --quick         # 2 recordings x 30 frames, 1 worker, 1 repeat
    .venv/bin/python benchmarks/bench_batch.py --robot milling_arm --frames 100   # robot recordings: fitted too

Issue 19's target: the batch takes at most 1.2 x (single-recording time x recordings / workers). The
recordings are human17 chains moving smoothly (chainspace.synthetic.views.swing_motion), seen by a
low-motion orbit camera with 1 px noise, saved as CSV tracks; each is reconstructed and its files
written as ``chainspace batch`` does (chainspace.batch.process_recording).

With ``--robot NAME`` (a shipped robot) the recordings are that robot instead, filmed by
``chainspace.synthesize`` (joints over their usual ranges, a static weak-perspective camera, 1 px), each
reconstructed and fitted (``fit_joint_angles``), seconds of work per recording rather than a fraction of one.
The batch's workers run the compiled robot solver on one thread each; the in-process recordings run it on
one thread too (``CHAINSPACE_THREADS=1``), the work of one worker.

"Single-recording time" is measured two ways, and the table gives the ratio for each:

* **in-process**: the 40 recordings one after the other in one warm process (imports done) with
  ``process_recording``, divided by 40: the pure processing time, measured in the same conditions as
  the batch (the machine may be shared: a single time taken at a quiet moment would flatter it);
* **command**: the wall time of ``chainspace reconstruct TRACKS --chain human17 --out DIR`` (robots:
  ``chainspace fit TRACKS --urdf NAME --out DIR``) in a fresh process (what running the recordings one by
  one costs: the interpreter and imports included).

The batch is timed end to end through ``run_batch`` (manifest read, local cluster started and closed,
summary written), and again on a cluster started beforehand (``scheduler=`` a Client), which leaves out
the cluster's start and stop. "cores used" is the CPU time of the recordings (``cpu_seconds``) over the
batch's wall time: below the number of workers when the machine is shared.
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import chainspace as cs
from chainspace.batch import process_recording, read_manifest, run_batch
from chainspace.synthetic.views import observe, orbit_cameras, swing_motion


def make_recordings(folder: Path, n: int, frames: int, robot: str | None = None) -> Path:
    chain = cs.shipped(robot or "human17")
    rows = ["name,tracks,chain"]
    for i in range(n):
        if robot is None:
            X = swing_motion(chain, frames, seed=i)
            W = observe(X, orbit_cameras(frames, scale=400.0, seed=1000 + i), translations=[450.0, 450.0],
                        noise_px=1.0, seed=i)
        else:
            W = cs.synthesize(chain, n_frames=frames, noise_px=1.0, seed=i, camera="static").tracks
        cs.save_tracks(folder / f"rec_{i:03d}.csv", W, chain.joints)
        rows.append(f"rec_{i:03d},rec_{i:03d}.csv,{chain.name}")
    manifest = folder / "manifest.csv"
    manifest.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return manifest


def time_command(tracks: Path, out: Path, robot: str | None = None) -> float:
    exe = Path(sys.executable).with_name("chainspace")
    cmd = [str(exe), "reconstruct", str(tracks), "--chain", "human17", "--out", str(out)] if robot is None else \
        [str(exe), "fit", str(tracks), "--urdf", robot, "--out", str(out)]
    t = time.perf_counter()
    # a robot fit's exit code 1 means frames that did not converge, not a failed command; the process
    # inherits main's CHAINSPACE_THREADS=1
    subprocess.run(cmd, check=robot is None, capture_output=True)
    return time.perf_counter() - t


def _warm() -> None:
    import importlib

    from chainspace.batch import _PRELOAD

    for module in _PRELOAD:
        importlib.import_module(module)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recordings", type=int, default=40)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--repeat", type=int, default=3, help="runs of the single-recording command")
    ap.add_argument("--robot", default=None, help="a shipped robot (milling_arm, ...): robot recordings, fitted too")
    ap.add_argument("--quick", action="store_true", help="2 recordings x 30 frames, 1 worker, 1 repeat")
    args = ap.parse_args(argv)
    robots = [Path(name).stem for name in cs.list_shipped() if name.endswith(".urdf")]
    if args.robot is not None and args.robot not in robots:
        ap.error(f"--robot {args.robot!r} is not a shipped robot (shipped: {', '.join(robots)})")
    os.environ["CHAINSPACE_THREADS"] = "1"  # in-process recordings: one worker's share of the machine
    if args.quick:
        args.recordings, args.frames, args.workers, args.repeat = 2, 30, 1, 1
    n, workers = args.recordings, args.workers
    say = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731

    root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    try:
        manifest = make_recordings(root, n, args.frames, args.robot)
        recs = read_manifest(manifest)
        say(f"{n} recordings x {args.frames} frames in {root}; {workers} workers; load {os.getloadavg()}")

        process_recording(recs[0], root / "warm")  # imports, first-call costs
        t = time.perf_counter()
        serial = [process_recording(rec, root / "serial") for rec in recs]
        t_serial = time.perf_counter() - t
        t_inproc = t_serial / n
        cpu_serial = sum(f["cpu_seconds"] for f in serial)
        say(f"in-process, one after the other: {t_serial:.1f} s ({t_inproc:.2f} s each, CPU {cpu_serial:.1f} s)")
        cmd = [time_command(recs[i % n].tracks, root / f"cmd_{i}", args.robot) for i in range(args.repeat)]
        t_cmd = statistics.median(cmd)
        say(f"command single: {', '.join(f'{t:.2f}' for t in cmd)} s")

        t = time.perf_counter()
        res = run_batch(manifest, root / "batch_local", n_workers=workers, progress=False)
        t_local = time.perf_counter() - t
        assert not res.failed, res  # a robot's unconverged or unvalidated fit is a result, not a failure
        say(f"run_batch, local cluster started and closed: {t_local:.2f} s")

        from dask.distributed import Client, LocalCluster

        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            client.run(_warm)  # a running cluster's workers have done this already
            t = time.perf_counter()
            res2 = run_batch(manifest, root / "batch_running", scheduler=client, progress=False)
            t_running = time.perf_counter() - t
        assert not res2.failed, res2
        say(f"run_batch, cluster already running: {t_running:.2f} s")
        load = os.getloadavg()
        cores = {name: sum(r["cpu_seconds"] for r in r_.rows) / wall
                 for name, r_, wall in (("local", res, t_local), ("running", res2, t_running))}
    finally:
        shutil.rmtree(root, ignore_errors=True)

    what = "human17 recordings" if args.robot is None else f"{args.robot} recordings (reconstructed and fitted)"
    print(f"{n} {what} x {args.frames} frames, {workers} workers (threads_per_worker=1), "
          f"{os.cpu_count()} cores, load average at the end {load[0]:.1f}; one after the other in one process: "
          f"{t_serial:.1f} s wall, {cpu_serial:.1f} s CPU")
    print()
    print("| batch run | wall s | cores used | single-recording basis | single s | target s (1.2 x single x "
          f"{n} / {workers}) | batch / target |")
    print("|---|---|---|---|---|---|---|")
    for name, key, wall in (("run_batch, local cluster (start + stop included)", "local", t_local),
                            ("run_batch, cluster already running", "running", t_running)):
        command = "`chainspace reconstruct` command" if args.robot is None else "`chainspace fit` command"
        for basis, single in (("in-process, one after the other", t_inproc), (command, t_cmd)):
            target = 1.2 * single * n / workers
            print(f"| {name} | {wall:.1f} | {cores[key]:.2f} | {basis} | {single:.2f} | {target:.1f} | "
                  f"{wall / target:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
