"""Figures with matplotlib: convergence, joint angles, per-joint errors, robustness sweeps.

Every function writes one file, PNG or SVG by the path's suffix (PDF works too), through
:func:`chainspace.io.results.atomic_write`, and returns its path. Figures are bare matplotlib Figures
rendered by Agg: no screen, no pyplot state. Figures show millimetres and degrees; the inputs are SI (metres, radians).
"""

from __future__ import annotations

import math
import os
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import TrackError
from ..io.results import atomic_write, check_writable
from ..robot.result import playback_fps, reprojection_rms

__all__ = ["plot_convergence", "convergence_notes", "plot_joint_angles", "plot_joint_errors", "plot_error_sweep"]

_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}


def _figure(nrows: int = 1, ncols: int = 1, *, sharex: bool = False, **kw: Any) -> tuple[Any, Any]:
    # A bare Figure renders with Agg without touching pyplot: no window, no global state left open.
    from matplotlib.figure import Figure

    fig = Figure(**kw)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=sharex)
    return fig, axes


def _save(fig: Any, path: str | os.PathLike, overwrite: bool, layout: bool = True) -> Path:
    path = Path(path)
    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise TrackError(f"{path}: plots are written as .png, .svg or .pdf, not {path.suffix or 'no suffix'!r}")
    if layout:  # (else the caller laid it out)
        fig.tight_layout()
    with atomic_write(path, "wb", overwrite) as f:
        fig.savefig(f, format=fmt, dpi=120)
    return path


def plot_convergence(rec: Any, path: str | os.PathLike, *, fit: Any = None, overwrite: bool = False) -> Path:
    """Reprojection error per iteration of each stage, the refinement's own objective, and, when known,
    the 3D error (mm), with a caption that says what each curve is (:func:`convergence_notes`).

    ``rec.history`` maps a stage to series: ``"reprojection"`` (image units, RMS), ``"objective"`` (the
    refinement's E after every block) and ``"error_3d"`` (metres); ``"selection"`` the track scores that
    chose between the stages. Stages are drawn one after the other on a common iteration axis, like the
    convergence figure of Wandt et al. (2017). ``fit``: a robot fit of the same tracks
    (:class:`~chainspace.robot.result.JointFit`), whose reprojection is drawn as a level for comparison.
    """
    history: Mapping[str, Mapping[str, Sequence[float]]] = getattr(rec, "history", None) or {}
    check_writable([path], overwrite)
    keys = ("reprojection", "error_3d")
    series = {s: h for s, h in history.items() if h and any(len(h.get(k, [])) for k in keys)}
    if not series:
        raise TrackError("this reconstruction has no convergence history to plot")
    has_3d = any(len(h.get("error_3d", [])) for h in series.values())
    has_e = any(len(h.get("objective", [])) > 1 for h in series.values())
    rows = [("reprojection", 1.0, "reprojection error (px RMS)")]
    rows += [("objective", None, "objective E / its start")] if has_e else []
    rows += [("error_3d", 1000.0, "3D error (mm)")] if has_3d else []
    notes = [line for note in convergence_notes(rec, fit) for line in textwrap.wrap(note, 130)]
    height = 2.6 * len(rows) + 0.16 * len(notes) + 0.4
    fig, axes = _figure(len(rows), 1, sharex=True, figsize=(7.2, height))
    colours = {stage: f"C{i}" for i, stage in enumerate(series)}
    offset = 0
    for stage, h in series.items():
        n = max(len(h.get(k, [])) for k in keys)
        for ax, (key, scale, _) in zip(axes[:, 0], rows):
            v = np.asarray(h.get(key, []), dtype=float)
            if not len(v):
                continue
            # E is logged after every block, several per iteration: spread over the stage's iterations
            x = offset + (np.linspace(0, max(n - 1, 0), len(v)) if scale is None else np.arange(len(v)))
            ax.plot(x, v * scale if scale is not None else v / v[0], marker="." if len(v) < 40 else None, label=stage,
                    color=colours[stage])
        offset += n
        for ax in axes[:, 0]:
            ax.axvline(offset - 0.5, color="0.8", lw=0.8)
    px = _fit_reprojection(fit)
    if px is not None:
        kind = "pinhole" if getattr(fit, "intrinsics", None) is not None else "weak-perspective"
        axes[0, 0].axhline(px, color="k", ls="--", lw=1, label=f"robot fit ({kind} camera)")
    for ax, (_, _, label) in zip(axes[:, 0], rows):
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(title="stage", fontsize="small")
    axes[-1, 0].set_xlabel("iteration")
    axes[0, 0].set_title("convergence")
    fig.tight_layout(rect=(0, (0.16 * len(notes) + 0.2) / height, 1, 1))
    fig.text(0.01, 0.01, "\n".join(notes), fontsize=7, va="bottom", ha="left")
    return _save(fig, path, overwrite, layout=False)


def _fit_reprojection(fit: Any) -> float | None:
    """A robot fit's reprojection error over all frames (px RMS), or None (no fit, or no tracks)."""
    px = None if fit is None else reprojection_rms(fit)
    return px if px is not None and np.isfinite(px) else None


def convergence_notes(rec: Any, fit: Any = None) -> list[str]:
    """The lines under the convergence plot: what the stages' reprojection measures, why the refinement's
    can rise, which stage was kept and on what score (``rec.history["selection"]``), and the robot
    fit's reprojection when ``fit`` is given."""
    history = getattr(rec, "history", None) or {}
    weak = [s for s in ("rigid", "kcs", "refine") if s in history]
    notes = [f"Reprojection of {' and '.join(weak)} through weak-perspective cameras, bone lengths free (scale-free): "
             "a camera close to the subject leaves a perspective misfit that these stages cannot remove."] if weak else []
    if "perspective" in history:
        notes.append("perspective: the same poses refined on the camera's rays (pinhole, known intrinsics).")
    if "refine" in history:
        notes.append("The refinement minimises E = reprojection + bone-length constancy + smoothness (normalised "
                     "to its start in the panel below), so its reprojection can rise while the bones settle.")
    sel = history.get("selection") or {}
    chosen = list(sel.get("chosen", []))
    if chosen and len(sel.get("kcs", [])) == 3 and len(sel.get("refine", [])) == 3:
        (a, a_rms, a_var), other = sel[chosen[0]], "kcs" if chosen[0] == "refine" else "refine"
        b, b_rms, b_var = sel[other]
        notes.append(f"Kept: {chosen[0]} (track score {a:.3g} = reprojection {a_rms:.3g} + bone-length variation "
                     f"{a_var:.3g}, both relative to the subject's size in the image; {other}: {b:.3g} = {b_rms:.3g} "
                     f"+ {b_var:.3g}).")
    px = _fit_reprojection(fit)
    if px is not None:
        kind = "its pinhole camera" if getattr(fit, "intrinsics", None) is not None else "a weak-perspective camera"
        notes.append(f"Robot fit: {px:.3g} px RMS through {kind}, with the robot's own bone lengths (its URDF): "
                     "the level to compare the stages with.")
    return notes


def _q_names(fit: Any) -> list[str]:
    names = list(getattr(fit, "joint_names", []) or [])
    return names or [f"q{i}" for i in range(np.shape(fit.q)[1])]


def plot_joint_angles(fit: Any, truth_q: Any, path: str | os.PathLike, *, fps: float | None = None,
                      joints: Sequence[str] | None = None, overwrite: bool = False) -> Path:
    """Fitted joint angles over time (degrees) against the truth, one panel per joint.

    ``fit.angles`` (F, nv) rad, one per joint (``fit.q`` where there are none); ``truth_q`` the same
    or (F, nq) in Pinocchio's layout, or None. Joints the fit marks not observable are drawn dashed.
    Joints it marks seen only relative to the first frame (``fit.relative``) are drawn, fitted and
    truth alike, as their change since frame 0, and labelled "relative to frame 0". ``joints`` picks a
    subset by name. A fit that carries standard deviations (``fit.q_std``) is drawn with a band of +-1
    standard deviation; its alternatives (other motions that fit the tracks as well, ``fit.alternatives``)
    as thin grey lines, and a joint they leave ambiguous (``fit.ambiguous``) is labelled so.
    """
    check_writable([path], overwrite)
    q = np.asarray(getattr(fit, "angles", fit.q), dtype=float)  # one angle per joint (continuous: radians)
    names = _q_names(fit)
    truth = None if truth_q is None else np.asarray(truth_q, dtype=float)
    if truth is not None and truth.shape != q.shape and truth.shape == np.shape(fit.q) and hasattr(fit, "kinematics"):
        truth = fit.kinematics().angles(truth)  # truth in Pinocchio's q layout: as angles too
    if truth is not None and truth.shape != q.shape:
        raise TrackError(f"truth joint angles have shape {truth.shape}, the fit's {q.shape}")
    pick = list(range(len(names))) if joints is None else [names.index(j) for j in joints if j in names]
    if not pick:
        raise TrackError(f"none of {list(joints or [])} is a joint of the fit ({', '.join(names)})")
    observable = np.asarray(getattr(fit, "observable", np.ones(len(names), bool)), dtype=bool)
    relative = np.asarray(getattr(fit, "relative", None) if getattr(fit, "relative", None) is not None
                          else np.zeros(0, bool), dtype=bool)
    relative = relative if relative.shape == (len(names),) else np.zeros(len(names), bool)
    std = getattr(fit, "q_std", None)
    std = np.asarray(std, float) if std is not None and np.shape(std) == q.shape else None
    alternatives = [np.asarray(a["angles"], float) for a in getattr(fit, "alternatives", None) or []
                    if np.shape(a.get("angles")) == q.shape]
    from ..robot.result import joint_flags

    ambiguous = joint_flags(fit, "ambiguous", len(names))
    ncols = 2 if len(pick) > 3 else 1
    nrows = math.ceil(len(pick) / ncols)
    fig, axes = _figure(nrows, ncols, figsize=(6.4 * ncols / 1.3, 1.9 * nrows + 0.6), sharex=True)
    t = np.arange(len(q)) / playback_fps(fit, fps)
    for k, i in enumerate(pick):
        ax = axes.flat[k]
        rel = bool(relative[i])
        since = (lambda a: np.unwrap(a - a[0])) if rel else (lambda a: a)  # noqa: E731
        tag = " (relative to frame 0)" if rel else ""
        if truth is not None:
            ax.plot(t, np.degrees(since(truth[:, i])), color="0.2", lw=1.2, label="truth" + tag)
        for n_alt, a in enumerate(alternatives):
            ax.plot(t, np.degrees(since(a[:, i])), color="0.6", lw=0.8, label=None if n_alt else "alternative")
        fitted = np.degrees(since(q[:, i]))
        if std is not None and np.isfinite(std[:, i]).any():
            band = np.degrees(std[:, i])
            ax.fill_between(t, fitted - band, fitted + band, color="C1", alpha=0.25, lw=0, label="+-1 std")
        held = not observable[i] and not rel  # not seen at all: drawn where the fit held it (its rest value)
        ax.plot(t, fitted, color="C1", lw=1.2, ls="-" if observable[i] else "--",
                label="fitted" + tag + (" (not observable: held)" if held else ""))
        label = f"{names[i]} (deg)" if not rel else f"{names[i]} (deg,\nrelative to frame 0)"
        ax.set_ylabel(label + ("\nAMBIGUOUS" if ambiguous[i] else "\nNOT OBSERVABLE" if held else ""))
        if rel:
            ax.legend(loc="best", fontsize="small")
        ax.grid(True, alpha=0.3)
    for ax in axes.flat[len(pick):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    axes.flat[0].legend(loc="best", fontsize="small")
    fig.suptitle("joint angles" + (": fitted vs truth" if truth is not None else ""))
    return _save(fig, path, overwrite)


def plot_joint_errors(report: Any, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Per-joint RMS and max angle errors (degrees) of a validation report, as bars.

    Reads ``report.to_dict()``: a ``"joints"`` entry, either a list of ``{"name", "rms_deg",
    "max_deg"}`` or a mapping name -> ``{"rms_deg", "max_deg"}``.
    """
    check_writable([path], overwrite)
    rows = _joint_rows(report)
    if not rows:
        raise TrackError("the validation report has no per-joint errors to plot (no truth joint angles?)")
    names = [r[0] for r in rows]
    rms = np.array([r[1] for r in rows], dtype=float)
    mx = np.array([r[2] for r in rows], dtype=float)
    fig, axes = _figure(1, 1, figsize=(max(4.0, 0.7 * len(names) + 1.5), 3.6))
    ax = axes[0, 0]
    x = np.arange(len(names))
    ax.bar(x - 0.2, rms, 0.4, label="RMS", color="C0")
    ax.bar(x + 0.2, mx, 0.4, label="max", color="C3", alpha=0.7)
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylabel("error (deg; mm for prismatic joints)")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend()
    ax.set_title("joint-angle error per joint" + (" (passed)" if getattr(report, "passed", False) else ""))
    return _save(fig, path, overwrite)


def _joint_rows(report: Any) -> list[tuple[str, float, float]]:
    d = report.to_dict() if hasattr(report, "to_dict") else dict(report)
    joints = d.get("joints", d.get("per_joint"))
    rows = []
    items = joints.items() if isinstance(joints, Mapping) else (
        (j.get("name", j.get("joint")), j) for j in (joints or []))
    for name, j in items:
        rms = j.get("rms_deg", j.get("rms"))
        mx = j.get("max_deg", j.get("max", rms))
        if rms is not None:
            rows.append((str(name), float(rms), float(mx if mx is not None else math.nan)))
    return rows


def plot_error_sweep(table: Any, path: str | os.PathLike, *, x: str | None = None, y: str = "error_mm",
                     group: str | None = None, overwrite: bool = False) -> Path:
    """Error against a swept quantity (noise px, missing fraction), one line per group.

    ``table`` is a list of dict rows (or a mapping column -> list). ``x`` defaults to the first of
    ``noise_px``, ``missing``, ``drop`` present; ``group`` (e.g. ``"dataset"`` or ``"pattern"``) splits
    the lines; ``y`` is the error column (mm by default).
    """
    check_writable([path], overwrite)
    rows = _rows(table)
    if not rows:
        raise TrackError("the sweep table is empty")
    cols = rows[0].keys()
    x = x or next((c for c in ("noise_px", "missing", "missing_fraction", "drop") if c in cols), None)
    if x is None or y not in cols:
        raise TrackError(f"the sweep table needs an x column and {y!r}; it has {', '.join(cols)}")
    group = group if group is not None else next((c for c in ("dataset", "pattern", "method", "suite")
                                                  if c in cols), None)
    lines: dict[str, list[tuple[float, float]]] = {}
    for r in rows:
        lines.setdefault(str(r.get(group, "")) if group else "", []).append((float(r[x]), float(r[y])))
    fig, axes = _figure(1, 1, figsize=(6.0, 3.8))
    ax = axes[0, 0]
    for label, pts in lines.items():
        pts.sort()
        ax.plot(*zip(*pts, strict=True), marker="o", label=label or None)
    ax.set_xlabel(x.replace("_", " "))
    ax.set_ylabel(y.replace("_", " "))
    ax.grid(True, alpha=0.3)
    if group:
        ax.legend(title=group)
    ax.set_title(f"{y.replace('_', ' ')} vs {x.replace('_', ' ')}")
    return _save(fig, path, overwrite)


def _rows(table: Any) -> list[dict[str, Any]]:
    if isinstance(table, Mapping):
        keys = list(table)
        return [dict(zip(keys, vals, strict=True)) for vals in zip(*(table[k] for k in keys), strict=True)]
    return [dict(r) for r in table]
