"""Point tracking in video (chainspace.track_points) on a generated scene with known point motion.

The scene: a static textured background; four textured square plates (smoothed random noise, as a
sticker or a cast surface looks) that move along smooth curves and rotate; and one plain shaded plate
(a painted robot link: no texture) with a point in its middle (nothing to track: lost at once) and
one just inside its edge (the edge holds it across, nothing along it: it slides, which is drift).
The clip is written as MP4 ('mp4v', as a phone or webcam would compress it) and tracked from it,
decoding included in the time. Key frames with the true positions every ``--every`` frames
re-anchor the tracks; the drift at each re-anchor is reported. ``--lk-only`` adds runs without the ECC refinement (Lucas-Kanade steps alone).

    .venv/bin/python benchmarks/bench_tracking.py                      # 640x480 and 1920x1080, 300 frames
    .venv/bin/python benchmarks/bench_tracking.py --sizes 640x480 --frames 120 --window 11 21
    .venv/bin/python benchmarks/bench_tracking.py --window 21 41 --lk-only   # the table in docs/benchmarks.md
    .venv/bin/python benchmarks/bench_tracking.py --lk-only --plot docs/_static/tracking_errors.png

Prints a table: frames/s of the tracking stage, RMS and 95th-percentile error against the truth (px,
over the tracked frames: key frames excluded), lost fraction, and the largest drift at a re-anchor,
for the textured and the plain points, with the load average of the machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _texture(rng: np.random.Generator, size: int, sigma: float) -> np.ndarray:
    import cv2

    noise = cv2.GaussianBlur(rng.uniform(0, 255, (size, size)).astype(np.float32), (0, 0), sigma)
    noise = (noise - noise.mean()) / (noise.std() + 1e-9)  # full contrast whatever the blur
    return np.clip(128 + 50 * noise, 0, 255).astype(np.uint8)


def make_scene(path: Path, width: int, height: int, n_frames: int, fps: float = 30.0, seed: int = 0
               ) -> tuple[np.ndarray, list[str], list[str]]:
    """Write the clip to ``path`` (MP4) and return the true point positions (F, J, 2) px, their names
    and their kinds (on a textured plate, in the middle of the plain one, at its edge)."""
    import cv2

    rng = np.random.default_rng(seed)
    s = width / 640  # the scene scales with the frame
    background = cv2.cvtColor(_texture(rng, max(width, height), 6 * s)[:height, :width], cv2.COLOR_GRAY2BGR)
    background = (0.6 * background + 40).astype(np.uint8)  # dimmer than the plates
    side = int(round(90 * s))
    plates = [cv2.cvtColor(_texture(rng, side, 2.5 * s), cv2.COLOR_GRAY2BGR) for _ in range(4)]
    # a painted link: no texture, only its shading across it (brighter in the middle, as a lit tube)
    shade = 150 + 50 * np.cos(np.linspace(-np.pi / 2, np.pi / 2, side))
    plain = np.repeat(np.repeat(shade[:, None, None], side, axis=1), 3, axis=2).astype(np.uint8)
    plates.append(plain)
    # each plate: centre on an ellipse-like curve, rotation, and the tracked point at an offset from its centre
    t = np.arange(n_frames) / fps
    # laid out so that no two plates ever overlap (occlusion is not what this measures)
    centres0 = np.array([[0.2, 0.25], [0.8, 0.25], [0.2, 0.75], [0.8, 0.75], [0.5, 0.5]]) * [width, height]
    amp = np.array([[30, 40], [25, 30], [30, 20], [20, 40], [25, 30]]) * s
    freq = np.array([0.31, 0.23, 0.41, 0.27, 0.35])
    spin = np.radians([20, -25, 15, 30, 10])  # amplitude of the rotation
    # the tracked points: (plate, offset from its centre px, kind); on the plain plate one in the middle
    # and one 4 px inside its lower edge (a painted link's outline against the background)
    points = [(k, o, "textured") for k, o in enumerate([[12, -8], [-15, 5], [8, 15], [0, -14]])]
    points += [(4, [0, 0], "plain, middle"), (4, [0, (side - 1) / 2 / s - 4], "plain, at its edge")]
    names = [f"textured_{k}" for k in range(4)] + ["plain_middle", "plain_edge"]
    kinds = [kind for _, _, kind in points]
    truth = np.empty((n_frames, len(points), 2))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path}")
    try:
        for f in range(n_frames):
            frame = background.copy()
            for k, plate in enumerate(plates):
                phase = 2 * np.pi * freq[k] * t[f]
                c = centres0[k] + amp[k] * [np.sin(phase), np.sin(1.3 * phase + k)]
                a = spin[k] * np.sin(0.7 * phase)
                R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
                # plate pixel (u, v) -> frame: R (u - centre of the plate) + c
                M = np.hstack([R, (c - R @ [(side - 1) / 2, (side - 1) / 2])[:, None]])
                cv2.warpAffine(plate, M, (width, height), dst=frame, flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_TRANSPARENT)
                for j, (plate_index, offset, _) in enumerate(points):
                    if plate_index == k:
                        truth[f, j] = c + R @ (np.asarray(offset) * s)
            writer.write(frame)
    finally:
        writer.release()
    return truth, names, kinds


def run(width: int, height: int, n_frames: int, every: int, folder: Path, window: int = 21,
        refine: bool = True) -> list[dict]:
    from chainspace.video.tracking import track_points

    video = folder / f"scene_{width}x{height}.mp4"
    truth, names, kinds = make_scene(video, width, height, n_frames)
    keyframes = {str(f): {n: truth[f, j].tolist() for j, n in enumerate(names)}
                 for f in range(0, n_frames, every)}
    t0, c0 = time.perf_counter(), time.process_time()
    result = track_points(video, keyframes, window=window, refine=refine)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    err = np.linalg.norm(result.tracks - truth[: result.n_frames], axis=2)
    err[list(range(0, n_frames, every))] = np.nan  # key frames are given, not tracked
    rows = []
    for label in dict.fromkeys(kinds):
        cols = [j for j, kind in enumerate(kinds) if kind == label]
        e = err[:, cols]
        seen = np.isfinite(e)
        tracked_frames = np.ones(len(e), bool)
        tracked_frames[::every] = False
        drift = [d for pts in result.drift.values() for n, d in pts.items() if names.index(n) in cols]
        rows.append({"size": f"{width}x{height}", "window": window, "points": label, "n": len(cols),
                     "frames": result.n_frames, "fps": result.n_frames / seconds,
                     "fps_cpu": result.n_frames / cpu, "refine": refine,
                     "rms_px": float(np.sqrt(np.mean(e[seen] ** 2))) if seen.any() else float("nan"),
                     "p95_px": float(np.percentile(e[seen], 95)) if seen.any() else float("nan"),
                     "lost": float(1 - seen[tracked_frames].mean()),
                     "confidence": float(result.confidence[tracked_frames][:, cols][seen[tracked_frames]].mean())
                     if seen.any() else float("nan"),
                     "drift_px": float(np.nanmax(drift)) if np.isfinite(drift).any() else float("nan"),
                     "drift_lost": int(np.isnan(drift).sum())})
    rows[0]["curves"] = (names, err, sorted(result.drift))
    return rows


def plot_errors(rows: list[dict], path: Path) -> None:
    """Tracking error against the truth over the frames, one panel per video, key frames marked."""
    from chainspace.bench.tracking import plot_track_errors

    plot_track_errors([(f"{r['size']}, window {r['window']} px, {'ECC refined' if r['refine'] else 'LK only'}",
                        *r["curves"]) for r in rows if "curves" in r], path)


def format_table(rows: list[dict], every: int) -> str:
    lines = [f"| video | points | frames/s (tracking, decoding included; per CPU-second) | RMS error px | "
             f"95th pct px | lost | "
             f"mean confidence where tracked | largest drift at a re-anchor (every {every} frames) px |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        drift = ("-" if np.isnan(r["drift_px"]) else f"{r['drift_px']:.2f}") + (
            f" ({r['drift_lost']} lost before)" if r["drift_lost"] else "")
        conf = "-" if np.isnan(r["confidence"]) else f"{r['confidence']:.2f}"
        rms, p95 = (("-", "-") if np.isnan(r["rms_px"]) else (f"{r['rms_px']:.2f}", f"{r['p95_px']:.2f}"))
        how = f"window {r['window']}" + (", ECC refined" if r["refine"] else ", LK only")
        lines.append(f"| {r['size']}, {r['frames']} frames, {how} | {r['n']} {r['points']} | "
                     f"{r['fps']:.0f} ({r['fps_cpu']:.0f}) | {rms} | {p95} | {100 * r['lost']:.1f}% | {conf} | "
                     f"{drift} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="*", default=["640x480", "1920x1080"])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--every", type=int, default=100, help="a key frame (true positions) every N frames")
    ap.add_argument("--window", type=int, nargs="*", default=[21], help="patch side(s) of the tracker, px")
    ap.add_argument("--plot", type=Path, help="write the error over the frames as a PNG")
    ap.add_argument("--lk-only", action="store_true", help="also run without the ECC refinement")
    ap.add_argument("--quick", action="store_true", help="640x480, 60 frames (a smoke run)")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.frames, args.every = ["640x480"], 60, 30
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            w, h = (int(v) for v in size.lower().split("x"))
            print(f"tracking {size}, {args.frames} frames ...", file=sys.stderr, flush=True)
            for window in args.window:
                for refine in (True, False) if args.lk_only else (True,):
                    rows += run(w, h, args.frames, args.every, Path(tmp), window, refine)
    print(f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    print(format_table(rows, args.every))
    if args.plot:
        plot_errors(rows, args.plot)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
