"""Figures with matplotlib: convergence, joint angles, per-joint errors, robustness sweeps.

Every function writes one file, PNG or SVG by the path's suffix (PDF works too), through
:func:`chainspace.io.results.atomic_write`, and returns its path. Figures are bare matplotlib Figures
rendered by Agg: no screen, no pyplot state. Figures show millimetres and degrees; the inputs are SI (metres, radians).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import TrackError
from ..io.results import atomic_write, check_writable

__all__ = ["plot_convergence", "plot_joint_angles", "plot_joint_errors", "plot_error_sweep"]

_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}


def _figure(nrows: int = 1, ncols: int = 1, *, sharex: bool = False, **kw: Any) -> tuple[Any, Any]:
    # A bare Figure renders with Agg without touching pyplot: no window, no global state left open.
    from matplotlib.figure import Figure

    fig = Figure(**kw)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=sharex)
    return fig, axes


def _save(fig: Any, path: str | os.PathLike, overwrite: bool) -> Path:
    path = Path(path)
    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise TrackError(f"{path}: plots are written as .png, .svg or .pdf, not {path.suffix or 'no suffix'!r}")
    fig.tight_layout()
    with atomic_write(path, "wb", overwrite) as f:
        fig.savefig(f, format=fmt, dpi=120)
    return path


def plot_convergence(rec: Any, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Reprojection error per iteration of each stage and, when known, the 3D error (mm).

    ``rec.history`` maps a stage to series: ``"reprojection"`` (image units, RMS) and ``"error_3d"``
    (metres). Stages are drawn one after the other on a common iteration axis, like the convergence
    figure of Wandt et al. (2017).
    """
    history: Mapping[str, Mapping[str, Sequence[float]]] = getattr(rec, "history", None) or {}
    check_writable([path], overwrite)
    keys = ("reprojection", "error_3d")
    series = {s: h for s, h in history.items() if h and any(len(h.get(k, [])) for k in keys)}
    if not series:
        raise TrackError("this reconstruction has no convergence history to plot")
    has_3d = any(len(h.get("error_3d", [])) for h in series.values())
    fig, axes = _figure(2 if has_3d else 1, 1, figsize=(6.4, 6.0 if has_3d else 3.6))
    offset = 0
    for stage, h in series.items():
        n = max(len(h.get(k, [])) for k in keys)
        for ax, key, scale in ((axes[0, 0], "reprojection", 1.0), (axes[-1, 0], "error_3d", 1000.0)):
            v = np.asarray(h.get(key, []), dtype=float)
            if len(v) and (key == "reprojection" or has_3d):
                ax.plot(offset + np.arange(len(v)), v * scale, marker="." if len(v) < 40 else None, label=stage)
        offset += n
        for ax in axes[:, 0]:
            ax.axvline(offset - 0.5, color="0.8", lw=0.8)
    axes[0, 0].set_ylabel("reprojection error (px RMS)")
    if has_3d:
        axes[1, 0].set_ylabel("3D error (mm)")
    for ax in axes[:, 0]:
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(title="stage")
    axes[-1, 0].set_xlabel("iteration")
    axes[0, 0].set_title("convergence")
    return _save(fig, path, overwrite)


def _q_names(fit: Any) -> list[str]:
    names = list(getattr(fit, "joint_names", []) or [])
    return names or [f"q{i}" for i in range(np.shape(fit.q)[1])]


def plot_joint_angles(fit: Any, truth_q: Any, path: str | os.PathLike, *, fps: float = 30.0,
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
    t = np.arange(len(q)) / fps
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
