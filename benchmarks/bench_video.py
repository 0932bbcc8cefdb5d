"""The video benchmark: rendered clips of a moving robot in, marker corners and joint angles out.

Each row renders a clip (:mod:`chainspace.video.render`, pybullet's CPU renderer) of a robot moving
along the milling contour (``synthesize(..., camera="pinhole", trajectory="milling")``), filmed by a
static pinhole camera at 1.5 reaches (f = 0.8-1.2 x the image width), with the robot's ArUco marker
map on its links; finds the markers (:func:`chainspace.video.markers.detect_markers`); and, from the
markers' centre tracks alone with the known intrinsics, reconstructs and fits the joint angles
(:func:`chainspace.reconstruct`, :func:`chainspace.fit_joint_angles`). Reported per row: render time
per frame, the share of the markers seen whole (by the renderer's truth) that were found, their
corner error against the rendered truth (px RMS and worst), the worst joint RMS error (degrees) and
the 3D error (mm).

Targets (issue 18): marker corners <= 0.5 px, joint RMS <= 1.5 degrees end to end from the video
with known intrinsics. Robots without a shipped marker map (``robots/<name>.markers.csv``) get the
render-time columns only.

Command: ``python benchmarks/bench_video.py`` (300 frames, every row; ``--frames 40`` for a short run,
``--rows milling_arm:640x480`` to pick rows).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

ROWS = [("milling_arm", (640, 480)), ("milling_arm", (1920, 1080)), ("ur10", (640, 480)), ("ur10", (1920, 1080))]
TARGET_CORNER_PX, TARGET_JOINT_DEG = 0.5, 1.5


def _urdf(robot: str) -> Path:
    from chainspace.io.descriptions import example_robot_urdf, shipped_path

    return shipped_path(robot) if robot.startswith("milling_arm") else example_robot_urdf(robot)


def run_row(robot: str, size: tuple[int, int], n_frames: int, seed: int, folder: Path) -> dict:
    from chainspace import fit_joint_angles, reconstruct, validate
    from chainspace.errors import ChainspaceError
    from chainspace.io.urdf import from_urdf, point_positions
    from chainspace.synthetic.robot import synthesize
    from chainspace.video.markers import detect_markers, load_marker_map, marker_chain, shipped_marker_map
    from chainspace.video.render import load_truth, render_trial

    urdf = _urdf(robot)
    try:
        mmap = load_marker_map(shipped_marker_map(robot), urdf=urdf)
    except ChainspaceError:
        mmap = None
    chain = from_urdf(urdf, extra_frames=mmap.extra_frames() if mmap else None)
    trial = synthesize(chain, n_frames=n_frames, camera="pinhole", noise_px=0.0, seed=seed, trajectory="milling",
                       image_size=size, distance_reaches=1.5)
    clip = folder / f"{robot}_{size[0]}x{size[1]}.mp4"
    res = render_trial(trial, clip, markers=mmap, seed=seed, overwrite=True)
    row = {"robot": robot, "size": f"{size[0]}x{size[1]}", "frames": n_frames, "render_s": res.seconds_per_frame}
    if mmap is None:
        return row
    t0 = time.perf_counter()
    found = detect_markers(clip, mmap)
    row["detect_fps"] = n_frames / (time.perf_counter() - t0)
    truth = load_truth(clip)
    vis = truth["marker_visible"]
    ok = np.isfinite(found.corners).all(axis=(-1, -2))
    err = np.linalg.norm(found.corners - truth["marker_corners"], axis=-1)[vis & ok]
    row["found_pct"] = 100.0 * (vis & ok).sum() / max(vis.sum(), 1)
    row["corner_rms_px"] = float(np.sqrt((err ** 2).mean())) if err.size else float("nan")
    row["corner_max_px"] = float(err.max()) if err.size else float("nan")
    mchain = marker_chain(urdf, mmap, names=found.seen)
    idx = [found.names.index(n) for n in mchain.joints]
    tracks, conf = found.centres[:, idx], found.confidence[:, idx]
    cam = trial.intrinsics.with_size(*size)
    t0 = time.perf_counter()
    rec = reconstruct(tracks, mchain, confidence=conf, seed=seed)
    fit = fit_joint_angles(rec, urdf, chain=mchain, tracks=tracks, confidence=conf, fps=trial.fps, intrinsics=cam)
    row["fit_s"] = time.perf_counter() - t0
    rep = validate(fit, trial.q, truth_positions=point_positions(mchain, trial.q))
    judged = [j["rms"] for j in rep.joints if j["judged"] and j["rms"] is not None and j["unit"] == "deg"]
    row["joint_deg"] = max(judged) if judged else float("nan")
    row["error_3d_mm"] = rep.error_3d_mm
    return row


def format_table(rows: list[dict]) -> str:
    def f(v, fmt):
        return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, fmt)

    lines = ["| robot | image | frames | render s/frame | markers found % | corner RMS px (<= 0.5) | corner worst px "
             "| worst joint RMS deg (<= 1.5) | 3D error mm | targets |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "joint_deg" in r:
            met = r["corner_rms_px"] <= TARGET_CORNER_PX and r["joint_deg"] <= TARGET_JOINT_DEG
            verdict = "met" if met else "not met"
        else:
            verdict = "no marker map: render only"
        lines.append(f"| {r['robot']} | {r['size']} | {r['frames']} | {f(r['render_s'], '.2f')} | "
                     f"{f(r.get('found_pct'), '.0f')} | {f(r.get('corner_rms_px'), '.2f')} | "
                     f"{f(r.get('corner_max_px'), '.2f')} | {f(r.get('joint_deg'), '.2f')} | "
                     f"{f(r.get('error_3d_mm'), '.1f')} | {verdict} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=8)
    ap.add_argument("--rows", nargs="*", help="robot:WxH, e.g. milling_arm:640x480 (default: every row)")
    ap.add_argument("--keep", type=Path, help="keep the rendered clips in this folder")
    args = ap.parse_args()
    rows = ROWS if not args.rows else [(r.split(":")[0], tuple(int(v) for v in r.split(":")[1].split("x")))
                                       for r in args.rows]
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for robot, size in rows:
            t0 = time.perf_counter()
            out.append(run_row(robot, size, args.frames, args.seed, folder))
            print(f"{robot} {size[0]}x{size[1]}: {time.perf_counter() - t0:.0f} s", flush=True)
    print(format_table(out))


if __name__ == "__main__":
    main()
