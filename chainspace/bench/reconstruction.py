"""The benchmark protocol of Wandt et al. (2017, Table 1), extended, and its markdown table.

Protocol. For every sequence of a group and every camera path (``n_cameras`` per sequence, seeded):
a weak-perspective camera orbits the subject (:func:`chainspace.synthetic.views.orbit_cameras`: random
start azimuth, 10 degree sweep, random elevation in [0, 30] degrees), the subject spans 720 px of an
image 900 px tall (:func:`chainspace.synthetic.views.scale_for_span`), Gaussian pixel noise is added, and
every method reconstructs from the tracks alone with the chain's shipped rest pose as the initial
pose (for human17: the mean pose of CMU subjects 02, 07 and 16, never subject 35). The 3D error is
the paper's: per-frame rigid Procrustes alignment, mean joint distance, mean over frames; the
similarity variant also aligns scale. Errors are averaged over sequences and cameras of a group.

Columns: the initial pose alone (the rest pose in every frame), the rigid Tomasi-Kanade
factorization, the literal KCS (Algorithm 1), and chainspace's default pipeline.

Robot rows are produced by :mod:`chainspace.bench.robots`; :func:`run_benchmark` accepts extra
row producers (``extra=[callable(noise_levels, quick) -> list[Row]]``) and prints them in the same
table.
"""

from __future__ import annotations

import time
import warnings
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ChainspaceError
from ..metrics import error_3d
from ..synthetic.views import observe, orbit_cameras, scale_for_span

__all__ = ["Row", "sequence_groups", "evaluate_sequence", "run_benchmark", "format_table", "COLUMNS",
           "IMAGE_HEIGHT_PX", "SPAN_PX", "run_speed", "format_speed", "STATIC_SETS", "static_set",
           "run_static_benchmark", "format_static_table"]

IMAGE_HEIGHT_PX = 900
SPAN_PX = 0.8 * IMAGE_HEIGHT_PX
COLUMNS = ("initial pose", "rigid (Tomasi-Kanade)", "KCS (Algorithm 1)", "chainspace default")
_METHOD = {"rigid (Tomasi-Kanade)": "rigid", "KCS (Algorithm 1)": "kcs", "chainspace default": "default"}


@dataclass
class Row:
    """One table row: a sequence group at one noise level; per column (rigid mm, similarity mm, s)."""

    group: str
    noise_px: float
    n_runs: int
    cells: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    note: str = ""


def sequence_groups(names: Iterable[str] | None = None, *, quick: bool = False) -> dict[str, Any]:
    """{group: (chain, [poses (F, J, 3), ...], note)} of the groups whose data are available.

    Groups: walk35 (CMU subject 35 walks), walks 02/07/16, run09 (CMU subject 09 runs), and the
    DeepMimic jump and cartwheel. ``quick`` keeps at most 3 sequences per group.
    """
    from ..io import datasets

    human = datasets.human17()
    want = list(names) if names else ["walk35", "walk 02/07/16", "run09", "jump (DeepMimic)", "cartwheel (DeepMimic)"]
    out: dict[str, Any] = {}
    for g in want:
        try:
            if g == "walk35":
                seqs = [datasets.cmu_walk(35, amc.stem.split("_")[1]) for _, amc in datasets.cmu_trials(35)]
                out[g] = (human, seqs, "20 trials")
            elif g == "walk 02/07/16":
                seqs = [datasets.cmu_walk(s, amc.stem.split("_")[1]) for s in (2, 7, 16)
                        for _, amc in datasets.cmu_trials(s)]
                out[g] = (human, seqs, "rest pose made from these subjects")
            elif g == "run09":
                out[g] = (human, datasets.cmu09_runs(), "")
            elif g.endswith("(DeepMimic)"):
                chain, poses = datasets.deepmimic_clip(g.split()[0])
                # The humanoid's zero pose is planar (arms down, straight legs): it cannot tell
                # front from back. Start from the human17 mean pose (CMU 02/07/16) on its joints.
                mean = human.subset(chain.joints).rest_pose
                out[g] = (chain.with_rest_pose(mean), [poses], "initial pose: human17 rest pose")
            else:
                raise ChainspaceError(f"unknown sequence group {g!r}")
        except ChainspaceError as exc:
            if "unknown sequence group" in str(exc):
                raise
            continue
        if not out.get(g, (None, []))[1]:
            out.pop(g, None)
        elif quick:
            chain, seqs, note = out[g]
            out[g] = (chain, seqs[:3], note)
    return out


def evaluate_sequence(poses: np.ndarray, chain: Any, *, noise_px: float, seed: int,
                      columns: Sequence[str] = COLUMNS) -> dict[str, tuple[float, float, float]]:
    """Errors (rigid m, similarity m, seconds) of every column on one sequence and one camera path."""
    from ..reconstruction.pipeline import reconstruct

    F = len(poses)
    P = orbit_cameras(F, scale=scale_for_span(poses, SPAN_PX), seed=seed)
    W = observe(poses, P, translations=np.array([IMAGE_HEIGHT_PX / 2] * 2), noise_px=noise_px, seed=seed + 1)
    out = {}
    for col in columns:
        t0 = time.perf_counter()
        if col == "initial pose":
            pred = np.broadcast_to(chain.rest_pose, poses.shape)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                pred = reconstruct(W, chain, method=_METHOD[col]).poses
        dt = time.perf_counter() - t0
        out[col] = (error_3d(pred, poses), error_3d(pred, poses, scale=True), dt)
    return out


def _seed(*parts: Any) -> int:
    return zlib.crc32("/".join(map(str, parts)).encode()) & 0x7FFFFFFF


def run_benchmark(
    groups: Iterable[str] | None = None,
    *,
    noise_levels: Sequence[float] = (0.0, 2.0, 5.0),
    n_cameras: int | None = None,
    quick: bool = False,
    columns: Sequence[str] = COLUMNS,
    extra: Sequence[Callable[..., list[Row]]] = (),
    progress: Callable[[str], None] | None = None,
) -> list[Row]:
    """Run the protocol; returns the rows (print them with :func:`format_table`).

    ``n_cameras`` camera paths per sequence: 20 (the paper) by default, 3 when ``quick`` (which also
    keeps at most 3 sequences per group).
    """
    n_cameras = n_cameras if n_cameras is not None else (3 if quick else 20)
    rows = []
    for name, (chain, seqs, note) in sequence_groups(groups, quick=quick).items():
        for noise in noise_levels:
            acc: dict[str, list[tuple[float, float, float]]] = {c: [] for c in columns}
            for i, poses in enumerate(seqs):
                for cam in range(n_cameras):
                    res = evaluate_sequence(poses, chain, noise_px=noise, seed=_seed(name, i, cam), columns=columns)
                    for c, v in res.items():
                        acc[c].append(v)
            cells = {c: tuple(float(x) for x in np.mean(v, axis=0)) for c, v in acc.items() if v}
            rows.append(Row(name, float(noise), len(seqs) * n_cameras, cells, note))
            if progress:
                progress(f"{name} at {noise:g} px: done ({len(seqs)} sequences x {n_cameras} cameras)")
    for producer in extra:
        rows.extend(producer(noise_levels, quick))
    return rows


def format_table(rows: Sequence[Row], columns: Sequence[str] = COLUMNS) -> str:
    """One markdown table: per column 'rigid / similarity mm (s per sequence)'."""
    head = "| sequences | noise px | runs | " + " | ".join(columns) + " |"
    sep = "|---|---:|---:|" + "---:|" * len(columns)
    lines = [head, sep]
    for r in rows:
        cells = []
        for c in columns:
            if c in r.cells:
                rig, sim, sec = r.cells[c]
                cells.append(f"{rig * 1000:.1f} / {sim * 1000:.1f} ({sec:.2f} s)")
            else:
                cells.append("-")
        name = r.group + (f" [{r.note}]" if r.note else "")
        lines.append(f"| {name} | {r.noise_px:g} | {r.n_runs} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("3D error in mm, rigid / similarity per-frame Procrustes alignment, mean over frames, "
                 "sequences and camera paths; seconds per sequence in brackets.")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ speed
def run_speed(sizes: Sequence[int] = (1_000, 10_000, 100_000), *, quick: bool = False,
              threads: Sequence[int | None] = (1, None), memory: bool = True,
              progress: Callable[[str], None] | None = None, min_time: float = 1.0) -> list[dict[str, Any]]:
    """Seconds, CPU seconds and frames/s of the KCS stage and of the default pipeline for each
    number of frames and each BLAS thread count (``reconstruct(..., blas_threads=)``: 1, and None
    for the BLAS library's default, all cores), and the peak memory per frame (tracemalloc, one
    BLAS thread, a separate run).

    A human17 chain in smooth motion (:func:`chainspace.synthetic.views.swing_motion` at 120 Hz), a
    low-motion orbit camera, 2 px noise. ``quick`` stops at 10,000 frames. Each method runs again
    until ``min_time`` seconds have passed (at least once) and the fastest run counts (wall clock,
    with its CPU time, all threads): on a shared machine the fastest run is the one least slowed
    by others.
    """
    import tracemalloc

    from ..io.datasets import human17
    from ..reconstruction.pipeline import reconstruct
    from ..synthetic.views import swing_motion

    def timed(W, chain, method, n_threads):
        best, spent = None, 0.0
        while best is None or spent < min_time:
            t0, c0 = time.perf_counter(), time.process_time()
            rec = reconstruct(W, chain, method=method, blas_threads=n_threads)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            spent += wall
            if best is None or wall < best[0]:
                best = (wall, cpu, rec)
        return best

    def peak(W, chain, method):
        tracemalloc.start()
        try:
            reconstruct(W, chain, method=method)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    chain = human17()
    rows = []
    for n in [n for n in sizes if not quick or n <= 10_000]:
        X = swing_motion(chain, n, fps=120.0, seed=0)
        P = orbit_cameras(n, scale=scale_for_span(X, SPAN_PX), seed=0)
        W = observe(X, P, translations=[IMAGE_HEIGHT_PX / 2] * 2, noise_px=2.0, seed=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mem = {m: peak(W, chain, m) / n for m in ("kcs", "default")} if memory else {}
            for n_threads in threads:
                t_kcs, cpu_kcs, _ = timed(W, chain, "kcs", n_threads)
                t_def, cpu_def, rec = timed(W, chain, "default", n_threads)
                rows.append({"frames": n, "threads": n_threads, "kcs_s": t_kcs, "kcs_cpu_s": cpu_kcs,
                             "default_s": t_def, "default_cpu_s": cpu_def,
                             "refine_s": rec.timings.get("refine", 0.0),
                             "kcs_iterations": len(rec.history["kcs"]["reprojection"]) - 1,
                             "refine_sweeps": rec.n_iter,
                             "kcs_bytes_per_frame": mem.get("kcs"), "default_bytes_per_frame": mem.get("default")})
                if progress:
                    progress(f"{n} frames, BLAS threads {n_threads or 'all'}: KCS {t_kcs:.2f} s, default {t_def:.2f} s")
    return rows


def format_speed(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown table of :func:`run_speed` and the linearity of each stage (frames/s at the largest
    size over frames/s at the smallest, 1 = linear; wall clock and CPU time)."""
    def num(v, fmt):
        return "-" if v is None else format(v, fmt)

    def kb(v):
        return num(None if v is None else v / 1e3, ".3g")

    def per_cpu_s(n, v):
        return "-" if not v else f"{n / v:,.0f}"

    lines = ["| frames | BLAS threads | KCS s | KCS CPU s | KCS frames/s | KCS frames per CPU s | KCS iterations "
             "| refine frames/s | refine sweeps | default s | default CPU s | default frames/s "
             "| default frames per CPU s | KCS peak kB/frame | default peak kB/frame |",
             "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        n = r["frames"]
        lines.append(f"| {n:,} | {r['threads'] or 'all cores'} | {r['kcs_s']:.3g} | {num(r.get('kcs_cpu_s'), '.3g')} | "
                     f"{n / r['kcs_s']:,.0f} | {per_cpu_s(n, r.get('kcs_cpu_s'))} | "
                     f"{num(r.get('kcs_iterations'), 'd')} | "
                     f"{n / max(r['refine_s'], 1e-12):,.0f} | {num(r.get('refine_sweeps'), 'd')} | "
                     f"{r['default_s']:.3g} | {num(r.get('default_cpu_s'), '.3g')} | {n / r['default_s']:,.0f} | "
                     f"{per_cpu_s(n, r.get('default_cpu_s'))} | "
                     f"{kb(r.get('kcs_bytes_per_frame'))} | {kb(r.get('default_bytes_per_frame'))} |")
    lines.append("")
    lines.append("Fastest of repeated runs (wall clock); CPU s is that run's process time (all threads); "
                 "peak memory from tracemalloc, one BLAS thread.")
    for t in dict.fromkeys(r["threads"] for r in rows):
        sub = sorted((r for r in rows if r["threads"] == t), key=lambda r: r["frames"])
        if len(sub) < 2:
            continue
        lo, hi = sub[0], sub[-1]
        ratio = {k: (hi["frames"] / hi[k]) / (lo["frames"] / lo[k]) for k in ("kcs_s", "kcs_cpu_s", "default_s",
                                                                                 "default_cpu_s")}
        lines.append(f"Linearity, BLAS threads {t or 'all cores'}: frames/s at {hi['frames']:,} over {lo['frames']:,} "
                     f"frames: KCS {ratio['kcs_s']:.2f} (CPU {ratio['kcs_cpu_s']:.2f}), default "
                     f"{ratio['default_s']:.2f} (CPU {ratio['default_cpu_s']:.2f}); 1 = linear.")
    return "\n".join(lines)


# ------------------------------------------------------------------------- static pinhole cameras
STATIC_COLUMNS = ("ortho KCS", "ortho default", "pinhole KCS", "pinhole default", "pinhole + intrinsics")
MOTIONS = ("straight", "turning 360", "towards/away")


STATIC_SETS = ("tune", "held out", "DeepMimic", "dog")
DOG_FRAMES, DOG_STEP = 300, 2  # 10 s of each dog recording at 30 fps (the files are 60 fps)


def static_sequences(which: str) -> list[tuple[str, np.ndarray]]:
    """``[(name, poses)]`` of one set (:func:`static_set` also gives its chain)."""
    return static_set(which)[1]


def static_set(which: str) -> tuple[Any, list[tuple[str, np.ndarray]]]:
    """``(chain, [(name, poses)])``, Z-up metres. "tune" = CMU 35_01, 35_02 (the walks the defaults were
    looked at on); "held out" = walks 02_01, 07_01, 16_15 and the first subject-09 run (never tuned on);
    "DeepMimic" = the walk, run, jump and cartwheel clips (their 16-point humanoid, started from the
    human17 mean pose); "dog" = the dog motion capture in ``dog_mocap`` (BVH, cm; its own 26-point chain,
    rest pose from the file's offsets; first 10 s of each recording at 30 fps; non-commercial data:
    benchmark only). Empty when the data are missing."""
    from ..io import datasets

    human = datasets.human17()
    if which == "tune":
        return human, [(f"35_{t:02d}", datasets.cmu_walk(35, t)) for t in (1, 2)]
    if which == "held out":
        try:
            out = [(f"{s:02d}_{t:02d}", datasets.cmu_walk(s, t)) for s, t in ((2, 1), (7, 1), (16, 15))]
        except ChainspaceError:  # not bundled: only with the shared data
            return human, []
        runs = datasets.cmu09_runs()
        if runs:
            out.append(("09 run 1", runs[0]))
        return human, out
    if which == "DeepMimic":
        out, chain = [], None
        for clip in ("walk", "run", "jump", "cartwheel"):
            try:
                chain, poses = datasets.deepmimic_clip(clip)
            except ChainspaceError:
                continue
            out.append((clip, poses))
        if chain is None:
            return human, []
        return chain.with_rest_pose(human.subset(chain.joints).rest_pose), out
    if which == "dog":
        from ..io.bvh import load_bvh

        root = datasets.shared_data_dir()
        files = sorted((root / "dog_mocap").glob("*.bvh")) if root is not None else []
        out, chain = [], None
        for f in files:
            chain, poses, _ = load_bvh(f, unit="cm", name="dog")
            out.append((f.stem, datasets.to_z_up(poses[: DOG_FRAMES * DOG_STEP: DOG_STEP])))
        if chain is None:
            return human, []
        return chain.with_rest_pose(datasets.to_z_up(chain.rest_pose)), out
    raise ChainspaceError(f"unknown static set {which!r}; choose from {', '.join(STATIC_SETS)}")


def evaluate_static(poses: np.ndarray, chain: Any, motion: str, *, noise_px: float, seed: int) -> dict[str, float]:
    """3D errors (m) of every static column on one sequence, one motion and one random camera:
    distance uniform in [3, 5] m, f uniform in [700, 800] px, 640 x 480, height 1.5 m; for
    "straight" and "turning 360" the camera looks across the walk (90 degrees from its direction,
    +-30), for "towards/away" along it. Also the perspective result's reprojection (px)."""
    from ..reconstruction.pipeline import reconstruct
    from ..synthetic.views import orthographic_view, out_and_back, static_pinhole_view, turning_walk, walking_direction

    rng = np.random.default_rng(seed)
    X = {"straight": lambda p: p, "turning 360": turning_walk, "towards/away": out_and_back}[motion](poses)
    az = walking_direction(poses) + (0.0 if motion == "towards/away" else 90.0) + rng.uniform(-30, 30)
    W, cam = static_pinhole_view(X, distance_m=rng.uniform(3.0, 5.0), f_px=rng.uniform(700, 800), azimuth_deg=az,
                                 noise_px=noise_px, seed=seed + 1)
    Wo = orthographic_view(X, cam, noise_px=noise_px, seed=seed + 2)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for col, tracks, kw in (("ortho KCS", Wo, {"method": "kcs"}), ("ortho default", Wo, {}),
                                ("pinhole KCS", W, {"method": "kcs"}), ("pinhole default", W, {}),
                                ("pinhole + intrinsics", W, {"intrinsics": cam.camera})):
            t0 = time.perf_counter()
            rec = reconstruct(tracks, chain, **kw)
            out[col] = error_3d(rec.poses, X)
            out[col + " s"] = time.perf_counter() - t0
            if "intrinsics" in kw:
                out["reprojection px"] = rec.reprojection_error()
    return out


def run_static_benchmark(which: Sequence[str] = ("tune", "held out"), motions: Sequence[str] = MOTIONS,
                         noise_levels: Sequence[float] = (0.0, 2.0), n_cameras: int = 1,
                         progress: Callable[[str], None] | None = None, *,
                         max_sequences: int | None = None, max_frames: int | None = None) -> list[dict[str, Any]]:
    """One row per (sequence set, motion, noise): every run's errors kept (means and maxima).

    The DeepMimic and dog sets are filmed as recorded ("straight" only: they are not walks to turn);
    a set whose data are missing is reported as a row with no runs and a note. ``max_sequences``,
    ``max_frames``: at most that many sequences per set, frames per sequence (a quick run)."""
    rows = []
    for w in which:
        chain, seqs = static_set(w)
        seqs = [(n, p[:max_frames]) for n, p in (seqs[:max_sequences] if max_sequences else seqs)]
        if not seqs:
            rows.append({"set": w, "motion": "-", "noise": float("nan"), "runs": [], "sequences": "",
                         "note": "data missing (../shared/data or $CHAINSPACE_DATA): skipped"})
            if progress:
                progress(f"{w}: data missing, skipped")
            continue
        for motion in (motions if w in ("tune", "held out") else [m for m in motions if m == "straight"]):
            for noise in noise_levels:
                runs = []
                for name, poses in seqs:
                    for cam in range(n_cameras):
                        runs.append(evaluate_static(poses, chain, motion, noise_px=noise,
                                                    seed=_seed("static", name, motion, noise, cam)))
                        if progress:
                            progress(f"{w} {motion} {noise:g} px {name} cam {cam}: " + ", ".join(
                                f"{k} {v * 1000:.1f}" for k, v in runs[-1].items() if k in STATIC_COLUMNS))
                rows.append({"set": w, "motion": motion if w in ("tune", "held out") else "as recorded",
                             "noise": noise, "runs": runs, "sequences": ", ".join(n for n, _ in seqs)})
    return rows


def format_static_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: mean (max) 3D error in mm per column; the ratio intrinsics / ortho default (mean of
    per-run ratios, max); and whether the default without intrinsics ends at or below its KCS stage
    in the mean (and in how many runs)."""
    head = ("| set | motion | noise px | runs | " + " | ".join(STATIC_COLUMNS)
            + " | intrinsics / ortho default | pinhole default <= KCS (runs) | reproj. px (intr.) |")
    lines = [head, "|---|---|---:|---:|" + "---:|" * (len(STATIC_COLUMNS) + 3)]
    for r in rows:
        runs = r["runs"]
        if not runs:
            lines.append(f"| {r['set']} | {r.get('note', 'no runs')} | | 0 |" + " |" * (len(STATIC_COLUMNS) + 3))
            continue
        cells = []
        for c in STATIC_COLUMNS:
            v = np.array([x[c] for x in runs]) * 1000
            cells.append(f"{v.mean():.1f} ({v.max():.1f})")
        ratio = np.array([x["pinhole + intrinsics"] / x["ortho default"] for x in runs])
        d = np.array([x["pinhole default"] for x in runs])
        k = np.array([x["pinhole KCS"] for x in runs])
        ok = "yes" if d.mean() <= k.mean() else "**no**"
        rp = np.array([x["reprojection px"] for x in runs])
        lines.append(f"| {r['set']} | {r['motion']} | {r['noise']:g} | {len(runs)} | " + " | ".join(cells)
                     + f" | {ratio.mean():.2f} ({ratio.max():.2f}) | {ok} ({int((d <= k + 1e-12).sum())}/{len(runs)})"
                     + f" | {rp.mean():.2f} |")
    lines.append("")
    lines.append("3D error in mm (per-frame rigid Procrustes, mean over frames): mean over runs (max in brackets); "
                 "every run counts in every mean and max. Static pinhole camera 3-5 m away, f 700-800 px, 640x480; "
                 "ortho = the orthographic view of the same motion along the same camera axis at the same image scale.")
    return "\n".join(lines)
