"""Many recordings at once, on Dask: a manifest in, one output folder per recording and a summary out.

A manifest is a CSV file with a header row and one recording a row::

    name,tracks,chain,urdf,intrinsics,fps,truth
    walk_01,tracks/walk_01.csv,human17,,,,
    arm_a,tracks/arm_a.npz,milling_arm,,,30,truth/arm_a_q.npy

``name``, ``tracks`` and ``chain`` are required; ``urdf``, ``intrinsics``, ``fps`` and ``truth`` are
optional columns (and may be left empty in a row). Paths are relative to the manifest's folder.
``chain`` is a shipped name (``chainspace chains``) or a description file; a recording is a robot
when its chain is a URDF or its row names a ``urdf``. ``truth`` is, for a robot, the true joint angles
(as ``chainspace validate --truth``) and otherwise the true poses (as ``chainspace reconstruct
--truth``).

Each recording is processed as the single-recording commands do (:func:`process_recording`): the
tracks are read and reconstructed (``chainspace reconstruct``); for a robot, the joint angles are
fitted with a static camera (``chainspace fit``) and validated (``chainspace validate``). Its files go
to ``OUT/<name>/`` through a temporary folder renamed into place once every file is written, with a
``done.json`` marker holding the recording's figures. :func:`run_batch` sends the recordings to a
Dask cluster (a local one by default, one single-threaded worker process per core), skips the ones
whose folder is finished, reports a failing recording in the summary without stopping the others,
and writes ``OUT/summary.csv`` and ``OUT/summary.html``.
"""

from __future__ import annotations

import contextlib
import csv
import html
import inspect
import math
import os
import shutil
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ChainspaceError

__all__ = ["ManifestError", "Recording", "BatchResult", "read_manifest", "process_recording", "run_batch",
           "REQUIRED_COLUMNS", "OPTIONAL_COLUMNS", "DONE_MARKER", "SUMMARY_COLUMNS"]

REQUIRED_COLUMNS = ("name", "tracks", "chain")
OPTIONAL_COLUMNS = ("urdf", "intrinsics", "fps", "truth")
DONE_MARKER = "done.json"

# The summary's columns, in order (a recording's figures dict has these keys, None where not known).
SUMMARY_COLUMNS = (
    "name", "status", "skipped", "kind", "chain", "frames", "seconds", "cpu_seconds", "converged", "reprojection_px",
    "error_3d_mm", "fit_converged_fraction", "fit_reprojection_px", "fit_residual_3d_mm",
    "worst_joint", "worst_joint_rms", "worst_joint_unit", "worst_bone_error_pct", "validation_passed",
    "error", "line", "folder",
)


class ManifestError(ChainspaceError, ValueError):
    """A batch manifest that cannot be used; the message names the manifest, the line and the column."""


@dataclass
class Recording:
    """One row of a manifest, its paths made absolute.

    name : the recording's name (its output folder ``OUT/<name>/``).
    tracks : the 2D track file or folder.
    chain : a shipped description name, or the path of a description file.
    urdf : the robot's URDF for the fit, when the row names one.
    intrinsics : a camera intrinsics file, when the row names one (passed on as its path).
    fps : the frame rate, when the row gives one.
    truth : true joint angles (robots) or true poses (other chains), when the row names them.
    manifest, line : where the row is (line 1 is the header).
    problem : what is wrong with the row (a missing file, an unknown chain, a bad fps), or None.
    """

    name: str
    tracks: Path
    chain: str
    urdf: Path | None = None
    intrinsics: Path | None = None
    fps: float | None = None
    truth: Path | None = None
    manifest: Path | None = None
    line: int = 0
    problem: str | None = None

    @property
    def is_robot(self) -> bool:
        """Whether the recording is fitted as a robot: its chain is a URDF or it names one."""
        return self.urdf is not None or _chain_suffix(self.chain) == ".urdf"


@dataclass
class BatchResult:
    """What :func:`run_batch` did.

    rows : one figures dict per recording, in manifest order (keys :data:`SUMMARY_COLUMNS`).
    failed : names of the recordings that failed (an error, not an unconverged result).
    not_good : names of the recordings that ran but did not converge or failed validation.
    skipped : names of the recordings finished by an earlier run, not processed again.
    summary_csv, summary_html : the summary files.
    seconds : wall time of the whole batch.
    """

    rows: list[dict[str, Any]]
    failed: list[str]
    not_good: list[str]
    skipped: list[str]
    summary_csv: Path
    summary_html: Path
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when every recording succeeded (converged, and validated for robots)."""
        return not self.failed and not self.not_good

    def __repr__(self) -> str:
        return (f"BatchResult({len(self.rows)} recordings: {len(self.rows) - len(self.failed) - len(self.not_good)} "
                f"ok ({len(self.skipped)} from an earlier run), {len(self.not_good)} not converged or not "
                f"validated, {len(self.failed)} failed; {self.seconds:.1f} s; summary {self.summary_csv})")


# ---------------------------------------------------------------------------------------- manifest
def _chain_suffix(chain: str) -> str:
    """The description format of ``chain`` (a path or a shipped name), e.g. ".urdf"; "" when unknown."""
    suffix = Path(chain).suffix.lower()
    if suffix:
        return suffix
    from .io.descriptions import shipped_path

    try:
        return shipped_path(chain).suffix.lower()
    except ChainspaceError:
        return ""


def _bad_name(name: str) -> str | None:
    if not name:
        return "is empty"
    if name in (".", "..") or name.startswith(".") or any(c in name for c in '/\\:*?"<>|') or name != name.strip():
        return (f"{name!r} cannot be a folder name (no leading dot or surrounding spaces, none of "
                '/ \\ : * ? " < > |)')
    if name.lower().startswith("summary."):
        return f"{name!r} is reserved for the summary files"
    return None


def read_manifest(path: str | os.PathLike, *, strict: bool = True) -> list[Recording]:
    """Read a batch manifest (see :mod:`chainspace.batch` for its columns).

    Parameters
    ----------
    path
        The manifest CSV: a header row, then one recording a row. Paths in it are relative to its folder.
    strict
        When True (the default), a row that cannot be processed (a missing file, an unknown chain, a
        bad fps) raises; when False, the row is returned with ``problem`` saying what is wrong (how
        :func:`run_batch` reports it as a failed recording while the others run).

    Returns
    -------
    list of Recording
        In manifest order; blank lines and lines starting with ``#`` are skipped.

    Raises
    ------
    ManifestError
        ``manifest.csv:LINE: column 'COL': what is wrong``. Problems with the manifest as a whole
        (no such file, no header, a required column missing, an unknown column, a missing, bad or
        repeated name) raise also when ``strict`` is False.
    """
    manifest = Path(path)
    if not manifest.is_file():
        raise ManifestError(f"{manifest}: no such manifest file")
    try:
        text = manifest.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ManifestError(f"{manifest}: cannot read the manifest: {exc}") from None
    lines = [(i, line) for i, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise ManifestError(f"{manifest}: the manifest is empty (expected a header row: "
                            f"{','.join(REQUIRED_COLUMNS)}[,{','.join(OPTIONAL_COLUMNS)}])")
    rows = list(csv.reader([line for _, line in lines]))
    header_line, header = lines[0][0], [h.strip().lower() for h in rows[0]]
    where = f"{manifest}:{header_line}"
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise ManifestError(f"{where}: the header lacks the column{'s' if len(missing) > 1 else ''} "
                            f"{', '.join(map(repr, missing))} (found {', '.join(map(repr, header))}; required "
                            f"{', '.join(REQUIRED_COLUMNS)}, optional {', '.join(OPTIONAL_COLUMNS)})")
    unknown = [h for h in header if h not in REQUIRED_COLUMNS + OPTIONAL_COLUMNS]
    if unknown:
        raise ManifestError(f"{where}: unknown column {unknown[0]!r} (known: "
                            f"{', '.join(REQUIRED_COLUMNS + OPTIONAL_COLUMNS)})")
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise ManifestError(f"{where}: column {repeated[0]!r} appears more than once")
    if len(rows) == 1:
        raise ManifestError(f"{where}: the manifest has a header but no recordings")

    base = manifest.resolve().parent
    recordings: list[Recording] = []
    seen: dict[str, int] = {}
    for (line, _), values in zip(lines[1:], rows[1:]):
        if len(values) > len(header):
            raise ManifestError(f"{manifest}:{line}: {len(values)} values for {len(header)} columns")
        row = dict(zip(header, (v.strip() for v in values)))
        name = row.get("name", "")
        bad = _bad_name(name)
        if bad:
            raise ManifestError(f"{manifest}:{line}: column 'name': the name {bad}")
        if name in seen:
            raise ManifestError(f"{manifest}:{line}: column 'name': {name!r} is already the name on line "
                                f"{seen[name]}")
        seen[name] = line
        rec, problem = _recording(row, base, manifest, line)
        if problem is not None:
            if strict:
                raise ManifestError(problem)
            rec.problem = problem
        recordings.append(rec)
    return recordings


def _recording(row: dict[str, str], base: Path, manifest: Path, line: int) -> tuple[Recording, str | None]:
    """The Recording of one row, and the first problem found in it (or None)."""
    problems: list[str] = []

    def at(column: str, message: str) -> None:
        problems.append(f"{manifest}:{line}: column {column!r}: {message}")

    def file(column: str, required: bool = False) -> Path | None:
        value = row.get(column, "")
        if not value:
            if required:
                at(column, "is empty")
            return None
        p = Path(value).expanduser()
        p = p if p.is_absolute() else base / p
        if not p.exists():
            at(column, f"no such file: {value} (looked for {p})")
        return p

    tracks = file("tracks", required=True)
    chain = row.get("chain", "")
    if not chain:
        at("chain", "is empty (a shipped name, see 'chainspace chains', or a description file)")
    else:
        chain = _resolve_chain(chain, base, lambda m: at("chain", m))
    urdf = file("urdf")
    if urdf is not None and urdf.suffix.lower() != ".urdf":
        at("urdf", f"{row['urdf']} is not a .urdf file")
    intrinsics = file("intrinsics")
    truth = file("truth")
    fps = None
    if row.get("fps", ""):
        try:
            fps = float(row["fps"])
        except ValueError:
            at("fps", f"{row['fps']!r} is not a number of frames per second")
        else:
            if not (math.isfinite(fps) and fps > 0):
                at("fps", f"{row['fps']!r} is not a positive number of frames per second")
                fps = None
    rec = Recording(name=row["name"], tracks=tracks if tracks is not None else base / "", chain=chain, urdf=urdf,
                    intrinsics=intrinsics, fps=fps, truth=truth, manifest=manifest, line=line)
    return rec, (problems[0] if problems else None)


def _resolve_chain(value: str, base: Path, problem: Callable[[str], None]) -> str:
    """A description file (absolute path) or a shipped name; calls ``problem`` when it is neither."""
    from .io.descriptions import _LOADERS, list_shipped, shipped_path

    p = Path(value).expanduser()
    p = p if p.is_absolute() else base / p
    if p.is_file():
        if p.suffix.lower() not in _LOADERS:
            problem(f"{value}: unknown description format {p.suffix or '(no extension)'!r} "
                    f"(known: {', '.join(sorted(_LOADERS))})")
        return str(p)
    looks_like_path = "/" in value or "\\" in value or Path(value).suffix.lower() in _LOADERS
    if looks_like_path and not any(value == n for n in list_shipped()):
        problem(f"no such description file: {value} (looked for {p})")
        return str(p)
    try:
        shipped_path(value)
    except ChainspaceError as exc:
        problem(f"unknown chain: {exc}")
    return value


# ---------------------------------------------------------------------------------------- one recording
def _accepts(func: Callable[..., Any], keyword: str) -> bool:
    try:
        params = inspect.signature(func).parameters
    except (TypeError, ValueError):
        return False
    p = params.get(keyword)  # named: a **kwargs catch-all does not say the keyword is understood
    return p is not None and p.kind in (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)


def _options(rec: Recording, stages: dict[str, Callable[..., Any]]) -> dict[str, dict[str, Any]]:
    """Keyword arguments for each stage from the row's optional values, passed only to a stage whose
    signature takes them. Raises ChainspaceError when a value given is taken by none of the stages."""
    given = {"intrinsics": None if rec.intrinsics is None else str(rec.intrinsics), "fps": rec.fps}
    kwargs: dict[str, dict[str, Any]] = {stage: {} for stage in stages}
    for key, value in given.items():
        if value is None:
            continue
        takers = [stage for stage, func in stages.items() if _accepts(func, key)]
        if not takers and key == "fps":
            continue  # the frame rate is metadata where no stage models time (the reconstruction)
        if not takers:
            raise ChainspaceError(f"{rec.manifest}:{rec.line}: column {key!r}: intrinsics are not supported by this "
                                  f"version of chainspace for this recording ({' and '.join(stages)} "
                                  f"{'does' if len(stages) == 1 else 'do'} not take {key}=); leave the "
                                  "column empty")
        for stage in takers:
            kwargs[stage][key] = value
    return kwargs


def _finite(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _figures(rec: Recording, reconstruction: Any, fitted: Any, report: Any) -> dict[str, Any]:
    """The summary figures of one processed recording."""
    import numpy as np

    fig: dict[str, Any] = {k: None for k in SUMMARY_COLUMNS}
    frames = int(np.asarray(reconstruction.poses).shape[0])
    fig.update(name=rec.name, kind="robot" if fitted is not None else "chain", chain=reconstruction.chain.name,
               frames=frames, reprojection_px=_finite(reconstruction.reprojection_error()),
               line=rec.line, skipped=False)
    error_3d = [series["error_3d"][-1] for series in (reconstruction.history or {}).values()
                if series.get("error_3d")]
    if error_3d:
        fig["error_3d_mm"] = _finite(1000.0 * error_3d[-1])
    converged = bool(reconstruction.converged)
    if fitted is not None:
        conv = np.asarray(fitted.converged, dtype=bool)
        fig["fit_converged_fraction"] = float(conv.mean()) if conv.size else None
        converged = converged and bool(conv.all())
        if fitted.residual_3d is not None and np.isfinite(fitted.residual_3d).any():
            fig["fit_residual_3d_mm"] = _finite(1000.0 * np.nanmean(fitted.residual_3d) / (fitted.scale or 1.0))
    if report is not None:
        fig["fit_reprojection_px"] = _finite(report.reprojection_rms_px)
        fig["validation_passed"] = bool(report.passed)
        if report.error_3d_mm is not None and fig["error_3d_mm"] is None:
            fig["error_3d_mm"] = _finite(report.error_3d_mm)
        judged = [j for j in report.joints if j.get("judged") and j.get("rms") is not None]
        if judged:
            worst = max(judged, key=lambda j: j["rms"])
            fig.update(worst_joint=worst["name"], worst_joint_rms=_finite(worst["rms"]),
                       worst_joint_unit=worst.get("unit", "deg"))
        bone_errors = [abs(b["error_pct"]) for b in report.bones if b.get("error_pct") is not None]
        if bone_errors:
            fig["worst_bone_error_pct"] = _finite(max(bone_errors))
    fig["converged"] = converged
    fig["status"] = ("ok" if converged and fig["validation_passed"] in (None, True)
                     else "not converged" if not converged else "validation failed")
    return fig


@contextlib.contextmanager
def _staging(final: Path) -> Iterator[Path]:
    """A temporary folder beside ``final``, renamed to ``final`` when the block succeeds, removed if not."""
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.parent / f".{final.name}.partial-{uuid.uuid4().hex[:12]}"
    tmp.mkdir()
    try:
        yield tmp
        if final.exists():  # a run beside this one finished first; keep its output
            raise ChainspaceError(f"{final} appeared while this recording was processed (another run?)")
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _finished(folder: Path) -> dict[str, Any] | None:
    """The figures of a finished output folder, or None when it is not finished."""
    import json

    marker = folder / DONE_MARKER
    try:
        with open(marker, encoding="utf-8") as f:
            data = json.load(f)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def process_recording(rec: Recording, out_dir: str | os.PathLike) -> dict[str, Any]:
    """Process one recording as the single-recording commands do and write its files to
    ``out_dir/<name>/``; returns its figures.

    The tracks are read (``chainspace.load_tracks``) and reconstructed (``chainspace.reconstruct``, the
    default method; with the row's truth, the 3D error is added); a robot's joint angles are then fitted
    with a static camera (``chainspace.fit_joint_angles``) and validated (``chainspace.validate``,
    against the true joint angles when the row names them). ``reconstruction``, ``joint_angles`` and
    ``validation`` files are written as by ``chainspace.save_results``, then ``done.json`` with the
    figures, all in a temporary folder renamed to ``out_dir/<name>`` at the end: the folder appears
    complete or not at all. An ``intrinsics`` or ``fps`` value is passed to the stages whose
    signature takes it; when none does, the recording fails with a message saying so.

    Returns
    -------
    dict
        Keys :data:`SUMMARY_COLUMNS`: ``frames``, ``seconds`` (wall time of the processing) and
        ``cpu_seconds`` (CPU time of the process meanwhile),
        ``reprojection_px`` (RMS of the reconstruction), ``converged``, ``error_3d_mm`` (with a truth;
        for a robot without one, the fit's 3D residual in the robot's units), and for robots
        ``fit_converged_fraction``, ``fit_reprojection_px``, ``fit_residual_3d_mm``,
        ``worst_bone_error_pct``, ``validation_passed`` and, with true joint angles, ``worst_joint``
        with its RMS error (``worst_joint_unit``); ``status`` is "ok", "not converged" or
        "validation failed". Values not known are None.

    Raises
    ------
    ChainspaceError
        The row's problem (see :func:`read_manifest`), or whatever the stages raise; nothing is
        written to ``out_dir/<name>`` then.
    OutputExistsError
        ``out_dir/<name>`` exists and is not a finished output of a batch.
    """
    from .errors import OutputExistsError
    from .io.descriptions import load_chain
    from .io.results import save_results, write_json
    from .io.tracks import load_tracks
    from .reconstruction.pipeline import reconstruct

    start, cpu_start = time.perf_counter(), time.process_time()
    if rec.problem:
        raise ChainspaceError(rec.problem)
    final = Path(out_dir) / rec.name
    if final.exists():
        raise OutputExistsError(f"{final} exists and is not a finished batch output (no {DONE_MARKER}); "
                                "remove it or choose another --out")
    robot = rec.is_robot
    stages: dict[str, Callable[..., Any]] = {"reconstruct": reconstruct}
    if robot:
        from .robot.fit import fit_joint_angles
        from .robot.validation import validate

        stages["fit_joint_angles"] = fit_joint_angles
    kwargs = _options(rec, stages)

    chain = load_chain(rec.chain)
    W, conf, _ = load_tracks(rec.tracks, chain=chain)
    truth_poses = truth_q = None
    if rec.truth is not None:
        from .cli import _load_poses, _load_q

        if not robot:
            truth_poses = _load_poses(rec.truth, chain)
    reconstruction = reconstruct(W, chain, confidence=conf, truth=truth_poses, **kwargs["reconstruct"])
    fitted = report = None
    if robot:
        urdf = None if rec.urdf is None else str(rec.urdf)
        fitted = fit_joint_angles(reconstruction, urdf, camera="static", **kwargs["fit_joint_angles"])
        if rec.truth is not None:
            truth_q = _load_q(rec.truth, list(fitted.joint_names))
        report = validate(fitted, truth_q)
    fig = _figures(rec, reconstruction, fitted, report)
    with _staging(final) as tmp:
        for obj in (reconstruction, fitted, report):
            if obj is not None:
                save_results(obj, tmp)
        fig["seconds"] = time.perf_counter() - start
        fig["cpu_seconds"] = time.process_time() - cpu_start
        fig["folder"] = str(final)
        write_json(tmp / DONE_MARKER, fig)
    return fig


def _process_safely(rec: Recording, out_dir: str) -> dict[str, Any]:
    """:func:`process_recording` on a worker: an error becomes a failed row instead of an exception."""
    import warnings

    from .reconstruction.pipeline import _one_blas_thread

    start = time.perf_counter()
    try:
        # one recording is one core's work: BLAS threads would compete with the other workers
        with warnings.catch_warnings(), _one_blas_thread():
            warnings.simplefilter("ignore")  # e.g. ConvergenceWarning: the figures say it
            return process_recording(rec, out_dir)
    except Exception as exc:  # noqa: BLE001 - one recording's failure must not stop the batch
        return _failed_row(rec, exc, time.perf_counter() - start)


def _failed_row(rec: Recording, exc: BaseException | str, seconds: float | None = None) -> dict[str, Any]:
    fig: dict[str, Any] = {k: None for k in SUMMARY_COLUMNS}
    if isinstance(exc, str):
        message = exc
    elif isinstance(exc, (ChainspaceError, OSError)):
        message = str(exc) or type(exc).__name__
    else:
        message = f"{type(exc).__name__}: {exc}"
    fig.update(name=rec.name, status="failed", skipped=False, error=message, line=rec.line, seconds=seconds,
               kind="robot" if rec.problem is None and rec.is_robot else None)
    return fig


# ---------------------------------------------------------------------------------------- the batch
@contextlib.contextmanager
def _client(scheduler: str | Any | None, n_workers: int | None) -> Iterator[Any]:
    """A dask.distributed Client: of the cluster at ``scheduler`` (an address, a Client or a cluster),
    or of a new local cluster of single-threaded worker processes (closed on exit)."""
    try:
        import logging

        from dask.distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - dask is a dependency
        raise ChainspaceError(f"batch processing needs dask.distributed (pip install 'dask[distributed]'): {exc}"
                              ) from None
    if scheduler is not None and n_workers is not None:
        raise ChainspaceError("give either a scheduler (an existing cluster) or n_workers (a local one), not both")
    if scheduler is None:
        n = (os.cpu_count() or 1) if n_workers is None else int(n_workers)
        if n < 1:
            raise ChainspaceError(f"n_workers must be at least 1, not {n_workers}")
        import dask

        method = dask.config.get("distributed.worker.multiprocessing-method", "spawn")
        if method == "spawn" and _use_forkserver():
            method = "forkserver"
        with dask.config.set({"distributed.worker.multiprocessing-method": method}):
            # one worker per core: each worker's compiled robot solver on one thread, not on every core
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR, env={"CHAINSPACE_THREADS": "1"})
        try:
            with Client(cluster) as client:
                yield client
        finally:
            cluster.close()
    elif isinstance(scheduler, Client):
        yield scheduler
    else:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ChainspaceError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
        with client:
            yield client


# What the local workers need, imported once in the fork server and inherited by every worker it forks.
_PRELOAD = ["distributed", "numpy", "scipy.optimize", "scipy.sparse", "chainspace.batch", "chainspace.io.descriptions",
            "chainspace.io.tracks", "chainspace.io.results", "chainspace.reconstruction.pipeline"]


def _use_forkserver() -> bool:
    """Start the local workers from a fork server that has imported :data:`_PRELOAD`, where possible.

    Dask's default, spawn, starts every worker as a fresh interpreter that imports numpy, scipy,
    distributed and chainspace itself: about ten seconds for two workers on a busy two-core machine.
    Forked from a fork server that imported them once, the workers start in about a second (after
    the first batch of a process, the fork server is already running). Plain fork would be faster
    still but forks a process that runs threads (Dask's event loop): in the tests it hung once in a
    dozen runs. A start method set in the Dask configuration (other than the default) is kept.
    """
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    try:
        import distributed.utils as dist_utils
    except ImportError:  # pragma: no cover
        return False
    if not getattr(dist_utils, "_forkserver_preload_set", True):
        # distributed sets its own preload (every optional package it knows, slow) unless this is set
        multiprocessing.get_context("forkserver").set_forkserver_preload(_PRELOAD)
        dist_utils._forkserver_preload_set = True
    return True


def run_batch(
    manifest: str | os.PathLike,
    out: str | os.PathLike,
    scheduler: str | Any | None = None,
    n_workers: int | None = None,
    progress: bool = True,
) -> BatchResult:
    """Process every recording of ``manifest`` on a Dask cluster, each into ``out/<name>/``.

    Parameters
    ----------
    manifest
        The manifest CSV (see :func:`read_manifest`). A row with a problem (a missing file, an unknown
        chain, a bad fps) is reported as failed; the others run.
    out
        The output folder: ``out/<name>/`` per recording (see :func:`process_recording`),
        ``out/summary.csv`` and ``out/summary.html``. A recording whose folder holds ``done.json`` from
        an earlier run is skipped (its figures are read back), so a stopped batch resumes where it was.
    scheduler
        The address of a running Dask scheduler (``"tcp://host:8786"``), or a ``dask.distributed.Client``;
        None (default) starts a local cluster for the batch. The workers must have chainspace
        installed and see the manifest's files and ``out`` at the same paths.
    n_workers
        Workers of the local cluster (default one per core), each a process with one thread.
    progress
        Show a progress bar on stderr.

    Returns
    -------
    BatchResult
        ``rows`` (the figures of each recording, in manifest order), ``failed``, ``not_good``,
        ``skipped`` and the summary paths.

    Raises
    ------
    ManifestError
        The manifest as a whole cannot be used (see :func:`read_manifest`); nothing is processed.
    """
    start = time.perf_counter()
    recordings = read_manifest(manifest, strict=False)
    out_dir = Path(out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)

    results: dict[str, dict[str, Any]] = {}
    todo: list[Recording] = []
    for rec in recordings:
        if rec.problem:
            results[rec.name] = _failed_row(rec, rec.problem)
            continue
        done = _finished(out_dir / rec.name)
        if done is not None:
            row = {k: done.get(k) for k in SUMMARY_COLUMNS}
            row.update(name=rec.name, skipped=True, line=rec.line)
            results[rec.name] = row
            continue
        for stale in out_dir.glob(f".{rec.name}.partial-*"):  # left by a run that was killed
            shutil.rmtree(stale, ignore_errors=True)
        todo.append(rec)

    if todo:
        from dask.distributed import as_completed


        with _client(scheduler, n_workers) as client, \
                _progress(progress, len(recordings), len(recordings) - len(todo)) as advance:
            futures = {client.submit(_process_safely, rec, str(out_dir), pure=False,
                                     key=f"chainspace-batch-{rec.name}-{uuid.uuid4().hex[:8]}"): rec
                       for rec in todo}
            for future in as_completed(futures):
                rec = futures[future]
                try:
                    row = future.result()
                except Exception as exc:  # noqa: BLE001 - e.g. the worker died (KilledWorker)
                    row = _failed_row(rec, f"the Dask task failed: {type(exc).__name__}: {exc}")
                results[rec.name] = row
                advance(row)

    rows = [results[rec.name] for rec in recordings]
    summary_csv, summary_html = _write_summary(rows, out_dir)
    return BatchResult(
        rows=rows,
        failed=[r["name"] for r in rows if r["status"] == "failed"],
        not_good=[r["name"] for r in rows if r["status"] not in ("ok", "failed")],
        skipped=[r["name"] for r in rows if r.get("skipped")],
        summary_csv=summary_csv, summary_html=summary_html, seconds=time.perf_counter() - start,
    )


@contextlib.contextmanager
def _progress(show: bool, total: int, already: int) -> Iterator[Callable[[dict[str, Any]], None]]:
    """A rich progress bar on stderr; yields a function to call with each finished row."""
    if not show:
        yield lambda row: None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    counts = {"failed": 0}
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("{task.fields[note]}"))
    with Progress(*columns, console=Console(stderr=True, highlight=False)) as bar:
        note = f"{already} done earlier or unusable" if already else ""
        task = bar.add_task("recordings", total=total, completed=already, note=note)

        def advance(row: dict[str, Any]) -> None:
            if row["status"] != "ok":
                counts["failed"] += 1
            bar.update(task, advance=1, note=f"{row['name']}: {row['status']}"
                       + (f" ({counts['failed']} not ok)" if counts["failed"] else ""))

        yield advance


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _write_summary(rows: list[dict[str, Any]], out_dir: Path) -> tuple[Path, Path]:
    """summary.csv (one row per recording, :data:`SUMMARY_COLUMNS`) and summary.html, written atomically."""
    from .io.results import atomic_write

    csv_path, html_path = out_dir / "summary.csv", out_dir / "summary.html"
    with atomic_write(csv_path, "w", overwrite=True, newline="") as f:
        writer = csv.writer(f)
        writer.writerow(SUMMARY_COLUMNS)
        for row in rows:
            writer.writerow([_cell(row.get(k)) for k in SUMMARY_COLUMNS])

    n_ok = sum(r["status"] == "ok" for r in rows)
    n_failed = sum(r["status"] == "failed" for r in rows)
    colours = {"ok": "#e6f4e6", "failed": "#f8dddd"}
    head = "".join(f"<th>{html.escape(c)}</th>" for c in SUMMARY_COLUMNS if c != "folder")
    body = []
    for r in rows:
        cells = []
        for c in SUMMARY_COLUMNS:
            if c == "folder":
                continue
            text = html.escape(_cell(r.get(c)))
            if c == "name" and r.get("folder"):
                text = f'<a href="{html.escape(Path(r["folder"]).name)}/">{text}</a>'
            cells.append(f"<td>{text}</td>")
        body.append(f'<tr style="background:{colours.get(r["status"], "#fbf0d9")}">{"".join(cells)}</tr>')
    page = (
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>chainspace batch summary</title>"
        "<style>body{font-family:sans-serif;margin:1em}table{border-collapse:collapse;font-size:90%}"
        "td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}</style></head><body>\n"
        f"<h1>chainspace batch summary</h1>\n<p>{len(rows)} recordings: {n_ok} ok, "
        f"{len(rows) - n_ok - n_failed} not converged or not validated, {n_failed} failed. "
        "Units: seconds of processing, px, mm, degrees (or mm for prismatic joints), %.</p>\n"
        f"<table><thead><tr>{head}</tr></thead><tbody>\n" + "\n".join(body) + "\n</tbody></table></body></html>\n"
    )
    with atomic_write(html_path, "w", overwrite=True) as f:
        f.write(page)
    return csv_path, html_path
