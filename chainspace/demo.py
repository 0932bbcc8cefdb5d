"""The main job, end to end: a video of the milling arm in; its markers, 3D motion and joint angles out.

:func:`run_demo` (``make demo`` runs ``chainspace demo --out demo-output --overwrite``):

1. a video of the milling arm of ``robots/milling_arm.urdf`` is rendered (:mod:`chainspace.video.render`,
   pybullet's CPU renderer): its tool tip follows a rounded rectangle (a milling contour), ArUco
   markers of ``robots/milling_arm.markers.csv`` are stuck on its links, a static pinhole camera
   (640 x 480) films it. The clip is cached (:func:`cache_dir`) and rendered again only when missing: it
   is a function of the repository, the frame count and the seed, so it is the same on every machine;
2. the markers are found in every frame (:func:`chainspace.video.markers.detect_markers`) and their
   centres written as a tracks CSV (``frame, joint, x, y, confidence``) and read back: everything
   after this uses the video's tracks alone (and the known intrinsics, as from a calibration);
3. the motion is reconstructed from the tracks (:func:`chainspace.reconstruct`), the joint angles are
   fitted with the URDF and the camera's intrinsics (:func:`chainspace.fit_joint_angles`), and
   validated against the motion the video was rendered from (:func:`chainspace.validate`); the
   validation table is printed, with the markers' corner error against the rendered truth;
4. results go to files in ``out_dir``: the video and its truth, the camera, the tracks, the fitted joint
   angles (CSV/NPZ/JSON), the true joint angles, the validation report (JSON + markdown), and an
   overlay video (:func:`chainspace.draw_overlay`). The command line adds the HTML
   viewer and the plots from the returned summary (see :func:`chainspace.cli`).

Nothing is overwritten unless ``overwrite=True`` (:class:`~chainspace.errors.OutputExistsError`).
"""

from __future__ import annotations

import csv
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .errors import OutputExistsError
from .progress import time_left

__all__ = ["run_demo", "DEMO_FILES", "demo_clip", "cache_dir"]

# files run_demo writes into out_dir (checked before anything is written)
DEMO_FILES = ("video.mp4", "video.truth.npz", "camera.json", "markers.csv", "tracks.csv", "truth_joint_angles.csv",
              "joint_angles.csv", "joint_angles.npz", "joint_angles.json", "validation.json", "validation.md",
              "overlay.mp4")
DEMO_SIZE = (640, 480)  # image width, height (px)
DEMO_DISTANCE = 1.5  # camera distance in robot reaches: the smallest markers still span about 12 px
_CLIP_VERSION = 2  # bump when the rendering changes, so cached clips are rendered again


def cache_dir() -> Path:
    """Where rendered clips are cached: ``$CHAINSPACE_CACHE``, else ``$XDG_CACHE_HOME/chainspace``, else
    ``~/.cache/chainspace``."""
    if os.environ.get("CHAINSPACE_CACHE"):
        return Path(os.environ["CHAINSPACE_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "chainspace"


def demo_clip(n_frames: int = 300, seed: int = 8, *, size: tuple[int, int] = DEMO_SIZE,
              distance_reaches: float = DEMO_DISTANCE, robot: str = "milling_arm", cache: str | Path | None = None,
              progress: bool | Callable[[str], None] = False,
              count: Callable[[int, int], None] | None = None) -> tuple[Path, Any]:
    """(path of the rendered clip, the trial it films), rendering it into the cache when missing.

    The trial: ``synthesize(robot, camera="pinhole", trajectory="milling", seed=seed, ...)`` (the milling
    contour, a static pinhole camera of ``size`` at ``distance_reaches``), its chain the URDF's points
    plus the shipped markers' centres. The clip's truth NPZ sits beside it (:func:`~chainspace.video.render.truth_path`).
    ``count(done, total)``: the rendering's frame count, as it goes.
    """
    from .io.descriptions import shipped_path
    from .io.urdf import from_urdf
    from .synthetic.robot import synthesize
    from .video.markers import load_marker_map, shipped_marker_map
    from .video.render import render_trial, truth_path

    urdf = shipped_path(robot)
    mmap = load_marker_map(shipped_marker_map(robot), urdf=urdf)
    chain = from_urdf(urdf, extra_frames=mmap.extra_frames())
    trial = synthesize(chain, n_frames=n_frames, fps=30.0, camera="pinhole", noise_px=0.0, seed=seed,
                       trajectory="milling", image_size=size, distance_reaches=distance_reaches)
    w, h = size
    import hashlib

    # what is filmed (the URDF, the marker map, the motion and the camera) names the clip: a change to
    # any of them, including to how synthesize draws a trial, renders it again
    filmed = (trial.q, trial.intrinsics.K, trial.intrinsics.dist, trial.camera_R, trial.camera_t)
    digest = hashlib.sha256(urdf.read_bytes() + Path(mmap.source).read_bytes()
                            + b"".join(np.ascontiguousarray(a, float).tobytes() for a in filmed)).hexdigest()[:8]
    clip = Path(cache or cache_dir()) / f"{robot}_{w}x{h}_{n_frames}f_seed{seed}_d{distance_reaches:g}_v{_CLIP_VERSION}_{digest}.mp4"
    if clip.is_file() and truth_path(clip).is_file():
        _say(progress, f"      (cached clip {clip})")
        return clip, trial
    clip.parent.mkdir(parents=True, exist_ok=True)
    res = render_trial(trial, clip, markers=mmap, seed=seed, overwrite=True,
                       progress=count if count is not None else progress is True)
    _say(progress, f"      rendered {clip} ({res.seconds_per_frame:.2f} s a frame)")
    return clip, trial


def _say(progress: bool | Callable[[str], None], msg: str) -> None:
    if callable(progress):
        progress(msg)
    elif progress:
        print(msg, flush=True)


class _Ticker:
    """While a long stage runs, a plain progress line every ``every`` seconds (``what``: elapsed time, and
    the time left when ``expected_s`` gives an estimate), then one line with the time it took. Plain
    lines, so they show when the output is piped too."""

    def __init__(self, progress: bool | Callable[[str], None], what: str, *, every: float = 10.0,
                 expected_s: float | None = None) -> None:
        self.progress, self.what, self.every, self.expected_s = progress, what, every, expected_s
        self.t0 = time.perf_counter()
        self.done, self.total = 0, 0
        self._stop = None
        self._thread = None

    def count(self, done: int, total: int) -> None:
        """A stage's own count (``progress(done, total)`` of :func:`~chainspace.progress.progress_reporter`):
        the lines then give it, and the time left at the rate so far."""
        self.done, self.total = done, total

    def line(self) -> str:
        elapsed = time.perf_counter() - self.t0
        if self.total:
            return f"      ... {self.what}: {self.done}/{self.total}, {time_left(elapsed, self.done, self.total)}"
        text = f"      ... {self.what}: {elapsed:.0f} s elapsed"
        if self.expected_s:
            left = self.expected_s - elapsed
            text += f", about {left:.0f} s left" if left > 0 else ", taking longer than estimated"
        return text

    def __enter__(self) -> _Ticker:
        import threading

        self.t0 = time.perf_counter()
        self._stop = threading.Event()

        def run() -> None:
            while not self._stop.wait(self.every):
                _say(self.progress, self.line())

        if self.progress:
            self._thread = threading.Thread(target=run, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if exc[0] is None:
            _say(self.progress, f"      ... {self.what}: done in {time.perf_counter() - self.t0:.1f} s")


def _write_angles_csv(path: Path, q: np.ndarray, names: list[str], fps: float, overwrite: bool) -> None:
    from .io.results import atomic_write

    with atomic_write(path, "w", overwrite, newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "time_s"] + [f"{n} (rad)" for n in names])
        for k, row in enumerate(q):
            w.writerow([k, f"{k / fps:.4f}"] + [f"{v:.8f}" for v in row])


def run_demo(out_dir: str | Path, *, overwrite: bool = False, progress: bool | Callable[[str], None] = True,
             seed: int = 8, n_frames: int = 300, cache: str | Path | None = None) -> dict[str, Any]:
    """Run the milling-arm demo into ``out_dir`` and return a summary.

    ``n_frames`` frames at 30 fps; ``seed`` fixes the path's placement, the camera and the textures.
    Not every placement suits markers: with seed 4 the camera looks along the arm's plane from behind,
    the side markers are edge-on, 4 of the markers (of the first map's 19) are ever found and the fit
    fails (as it should: a camera set-up to change). The default (8) sees 6 to 8 markers a frame, on
    every link (seeds 0-13 were compared by the markers facing the camera, before any fit); its
    40-frame run passes with every joint within 0.2 degrees RMS.
    ``cache``: the folder of rendered clips (default :func:`cache_dir`). ``progress``: print stage
    messages (True), stay quiet (False) or call a function with each message. The summary holds the
    objects (``"reconstruction"``, ``"fit"``, ``"report"``, ``"truth_q"``, ``"truth_positions"``,
    ``"trial"``, ``"markers"`` (the detected :class:`~chainspace.video.markers.MarkerTracks`)),
    ``"marker_error_px"`` (RMS and worst corner error of the markers seen whole, against the rendered
    truth), ``"passed"``, ``"table"``, ``"message"``, ``"files"`` (paths written), ``"video"`` and
    ``"timings"`` (s).
    """
    from .io.results import check_writable, save_results
    from .io.tracks import load_tracks
    from .io.urdf import point_positions
    from .reconstruction.pipeline import reconstruct
    from .robot.fit import fit_joint_angles
    from .robot.validation import validate
    from .video.markers import detect_markers, marker_chain, save_marker_tracks
    from .video.render import load_truth, truth_path

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder")
    check_writable([out / f for f in DEMO_FILES], overwrite)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    w, h = DEMO_SIZE
    _say(progress, f"[1/6] the video: the milling arm with ArUco markers, {n_frames} frames, {w} x {h}, a static "
                   "pinhole camera (rendered once, then cached)")
    with _Ticker(progress, f"rendering {n_frames} frames", every=15.0) as ticker:
        clip, trial = demo_clip(n_frames, seed, cache=cache, progress=progress, count=ticker.count)
    timings["render"] = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for src, name in ((clip, "video.mp4"), (truth_path(clip), "video.truth.npz")):
        if (out / name).exists() and not overwrite:
            raise OutputExistsError(f"{out / name} already exists; pass overwrite=True (--overwrite) to replace it")
        shutil.copyfile(src, out / name)
        files.append(out / name)
    camera = trial.intrinsics.with_size(w, h)
    files.append(camera.save(out / "camera.json", overwrite=overwrite))
    video = out / "video.mp4"

    _say(progress, "[2/6] finding the markers in every frame (cv2.aruco) -> tracks.csv, read back as a tracker's file")
    t = time.perf_counter()
    found = detect_markers(video, _marker_map(), progress=False)
    timings["markers"] = time.perf_counter() - t
    truth = load_truth(video)
    err = _corner_error(found, truth)
    _write_corners(out / "markers.csv", found, overwrite)
    files.append(out / "markers.csv")
    tracks_path = save_marker_tracks(out / "tracks.csv", found, overwrite=overwrite)
    files.append(tracks_path)
    urdf = trial.chain.metadata["urdf_path"]
    chain = marker_chain(urdf, found.marker_map, names=found.seen)
    tracks, confidence, _ = load_tracks(tracks_path, chain=chain)
    _say(progress, f"      {len(found.seen)} of {len(found.names)} markers seen; corner error against the rendered "
                   f"truth {err['rms']:.2f} px RMS, worst {err['max']:.2f} px ({err['n']} corners)")

    F, J = tracks.shape[:2]
    _say(progress, f"[3/6] reconstructing the 3D motion from the tracks alone ({F} frames, {J} markers)")
    t = time.perf_counter()
    with _Ticker(progress, f"reconstructing {F} frames"):
        rec = reconstruct(tracks, chain, confidence=confidence, seed=seed)
    timings["reconstruct"] = time.perf_counter() - t

    _say(progress, f"[4/6] fitting the URDF's joint angles to {F} frames with the camera's intrinsics "
                   f"(f = {camera.fx:.0f} px; the longest stage)")
    t = time.perf_counter()
    from .progress import print_stages

    # the fit's own stages between the ticker's lines (a silent demo stays silent)
    with _Ticker(progress, f"fitting {F} frames", every=15.0), \
            print_stages("      ", say=lambda line: _say(progress, line)):
        fit = fit_joint_angles(rec, urdf, chain=chain, tracks=tracks, confidence=confidence, fps=trial.fps,
                               intrinsics=camera)
    timings["fit"] = time.perf_counter() - t

    _say(progress, f"[5/6] validating against the motion the video was rendered from ({F} frames)")
    truth_positions = point_positions(chain, trial.q)
    report = validate(fit, trial.q, truth_positions=truth_positions)
    table = report.table()
    _say(progress, "\n" + table + "\n")
    _say(progress, f"markers: {err['rms']:.2f} px RMS corner error ({err['n']} corners of markers seen whole; "
                   f"worst {err['max']:.2f} px)")

    _write_angles_csv(out / "truth_joint_angles.csv", trial.q, fit.joint_names, trial.fps, overwrite)
    files.append(out / "truth_joint_angles.csv")
    files += save_results(fit, out, overwrite=overwrite)
    files += save_results(report, out, overwrite=overwrite)
    files += _overlay(video, fit, out, overwrite, progress)
    # The HTML viewer and the plots are written by the command line (chainspace.cli) from this summary.
    timings["total"] = time.perf_counter() - t0
    _say(progress, f"results in {out}/ ({', '.join(p.name for p in files)}); "
                   f"{'PASSED' if report.passed else 'FAILED'} in {timings['total']:.1f} s")
    return {
        "reconstruction": rec, "fit": fit, "report": report, "truth_q": trial.q,
        "truth_positions": truth_positions, "trial": trial, "markers": found, "marker_error_px": err,
        "passed": report.passed, "table": table, "message": fit.message, "files": [str(p) for p in files],
        "timings": timings, "out_dir": str(out), "video": str(video),
    }


def _marker_map() -> Any:
    from .io.descriptions import shipped_path
    from .video.markers import load_marker_map, shipped_marker_map

    return load_marker_map(shipped_marker_map("milling_arm"), urdf=shipped_path("milling_arm"))


def _corner_error(found: Any, truth: dict[str, np.ndarray]) -> dict[str, float]:
    """RMS and worst distance (px) between detected corners and the rendered truth, over the markers the
    renderer saw whole (facing the camera, unoccluded, inside the image), and how many corners."""
    ids = list(truth["marker_ids"])
    idx = [ids.index(int(n.split("_")[1])) for n in found.names]
    true = truth["marker_corners"][:, idx]
    seen = truth["marker_visible"][:, idx] & np.isfinite(found.corners).all(axis=(-1, -2))
    e = np.linalg.norm(found.corners - true, axis=-1)[seen]
    if not e.size:
        return {"rms": float("nan"), "max": float("nan"), "n": 0, "missed": int(truth["marker_visible"].sum())}
    return {"rms": float(np.sqrt((e ** 2).mean())), "max": float(e.max()), "n": int(e.size),
            "missed": int((truth["marker_visible"][:, idx] & ~np.isfinite(found.corners).all(axis=(-1, -2))).sum())}


def _write_corners(path: Path, found: Any, overwrite: bool) -> None:
    """The detected corners: ``frame, marker, corner (0-3: OpenCV's order), x, y`` (px), seen ones only."""
    from .io.results import atomic_write

    with atomic_write(path, "w", overwrite, newline="") as f:
        wr = csv.writer(f)
        wr.writerow(["frame", "marker", "corner", "x", "y"])
        for k, m, c in zip(*np.nonzero(np.isfinite(found.corners[..., 0]))):
            x, y = found.corners[k, m, c]
            wr.writerow([k, found.names[m], c, f"{x:.3f}", f"{y:.3f}"])


def _overlay(video: Path, fit: Any, out: Path, overwrite: bool, progress: Any) -> list[Path]:
    """The fitted robot drawn over the video it was fitted from (``overlay.mp4``)."""
    from .video.overlay import draw_overlay

    _say(progress, "[6/6] drawing the fitted robot over the video (overlay.mp4)")
    return [draw_overlay(video, fit, out=out / "overlay.mp4", overwrite=overwrite, progress=progress is True)]
