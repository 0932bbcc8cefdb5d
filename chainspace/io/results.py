"""Writing results to disk safely, and reading them back.

Every file chainspace writes goes through :func:`atomic_write`: the content goes to a temporary file
in the target's folder, which is renamed over the target only once it is complete. An interrupted run
leaves the old file (or no file) in place, never half a file. An existing file is replaced only when
``overwrite=True`` (``--overwrite`` on the command line).

:func:`save_results` writes a reconstruction (:class:`chainspace.reconstruction.pipeline.Reconstruction`), a
robot joint-angle fit (:class:`chainspace.robot.fit.JointFit`) or a validation report
(:class:`chainspace.robot.validation.ValidationReport`) as

* ``<stem>.npz``: every array, loadable with :func:`load_results`;
* ``<stem>.csv``: a table (3D joint positions ``frame,joint,x,y,z`` in metres, or the joint angles
  ``frame,<joint names>`` in radians or metres for prismatic joints);
* ``<stem>.json``: a summary (convergence, iterations, timings, errors, names, units).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import IO, Any

import numpy as np

from ..errors import ChainspaceError, DescriptionNotFoundError, OutputExistsError, TrackError

__all__ = ["atomic_write", "check_writable", "result_paths", "save_results", "load_results", "to_jsonable",
           "write_json"]

UNITS = {"positions": "m", "bone_lengths": "m", "angles": "rad (revolute) or m (prismatic)",
         "tracks": "px (image units of the input)", "time": "s"}


def check_writable(paths: Iterable[str | os.PathLike], overwrite: bool = False) -> None:
    """Raise :class:`OutputExistsError` if any of ``paths`` exists and ``overwrite`` is False.

    Called before a multi-file write so that a refusal happens before the first file is written.
    """
    if overwrite:
        return
    existing = [str(p) for p in paths if Path(p).exists()]
    if existing:
        what = existing[0] if len(existing) == 1 else f"{existing[0]} (and {len(existing) - 1} more)"
        raise OutputExistsError(f"{what} already exists; pass overwrite=True (--overwrite) to replace it")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", overwrite: bool = False,
                 *, encoding: str = "utf-8", newline: str | None = None) -> Iterator[IO[Any]]:
    """Open ``path`` for writing through a temporary file renamed into place on success.

    ``mode`` is ``"w"`` (text, ``encoding``) or ``"wb"`` (bytes). The temporary file lives in the same
    folder (so the final ``os.replace`` is atomic); parent folders are created. If the block raises,
    the temporary file is removed and ``path`` is untouched. Raises :class:`OutputExistsError` when
    ``path`` exists and ``overwrite`` is False.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', not {mode!r}")
    target = Path(path)
    check_writable([target], overwrite)
    if target.is_dir():
        raise OutputExistsError(f"{target} is a folder; give a file name")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    except OSError as exc:
        raise ChainspaceError(f"cannot write {target}: {exc.strerror or exc}") from None
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        kwargs = {} if mode == "wb" else {"encoding": encoding, "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        check_writable([target], overwrite)  # another process may have created it meanwhile
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


# ---------------------------------------------------------------------------------------- JSON
def to_jsonable(value: Any) -> Any:
    """``value`` with numpy scalars/arrays as Python numbers/lists and NaN/inf as None (strict JSON)."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, (str, type(None))):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return str(value)


def write_json(path: str | os.PathLike, data: Any, *, overwrite: bool = False) -> Path:
    """Write ``data`` as indented strict JSON through :func:`atomic_write`."""
    with atomic_write(path, "w", overwrite) as f:
        json.dump(to_jsonable(data), f, indent=2, allow_nan=False)
        f.write("\n")
    return Path(path)


# ---------------------------------------------------------------------------------------- kinds
def _kind(obj: Any) -> str:
    if hasattr(obj, "q") and hasattr(obj, "joint_names"):
        return "joint_fit"
    if hasattr(obj, "poses") and hasattr(obj, "cameras"):
        return "reconstruction"
    if hasattr(obj, "to_dict") and hasattr(obj, "passed"):
        return "validation"
    raise TrackError(
        f"save_results cannot save a {type(obj).__name__}: expected a Reconstruction, a JointFit or a "
        "ValidationReport"
    )


_STEMS = {"reconstruction": "reconstruction", "joint_fit": "joint_angles", "validation": "validation"}
_SUFFIXES = {".npz", ".csv", ".json", ".md"}


def _stem_path(out: str | os.PathLike, kind: str) -> Path:
    out = Path(out)
    if out.suffix.lower() in _SUFFIXES:
        return out.with_suffix("")
    return out / _STEMS[kind]


def result_paths(out: str | os.PathLike, kind: str, formats: Sequence[str] = ("npz", "csv", "json")) -> list[Path]:
    """The files :func:`save_results` writes for a result of ``kind`` (``"reconstruction"``, ``"joint_fit"``
    or ``"validation"``) given ``out``: so that a caller can check them before the work starts."""
    if kind not in _STEMS:
        raise ValueError(f"kind must be one of {', '.join(_STEMS)}, not {kind!r}")
    stem = _stem_path(out, kind)
    formats = ("json", "md") if kind == "validation" else tuple(formats)
    return [stem.with_name(f"{stem.name}.{fmt}") for fmt in formats]


def _chain_arrays(chain: Any) -> dict[str, np.ndarray]:
    if chain is None:
        return {}
    arrays = {"joints": np.array(chain.joints, dtype=str),
              "bones": np.array(chain.bones, dtype=str).reshape(-1, 2),
              "chain_name": np.array(str(chain.name))}
    if getattr(chain, "rigid_links", ()):
        arrays["rigid_links"] = np.array(chain.rigid_links, dtype=str).reshape(-1, 2)
    if chain.rest_pose is not None:
        arrays["rest_pose"] = np.asarray(chain.rest_pose)
    if chain.metadata:  # e.g. a URDF chain's q_rest and extra frames (the tool tip)
        arrays["chain_metadata_json"] = np.array(json.dumps(to_jsonable(chain.metadata), allow_nan=False))
    return arrays


def _array_or_none(value: Any) -> np.ndarray | None:
    return None if value is None else np.asarray(value)


def _final(history: dict, key: str) -> dict[str, float]:
    """Last value of ``history[stage][key]`` per stage."""
    out = {}
    for stage, series in (history or {}).items():
        values = (series or {}).get(key)
        if values is not None and len(values):
            out[stage] = float(values[-1])
    return out


def _reconstruction_summary(rec: Any) -> dict[str, Any]:
    chain = getattr(rec, "chain", None)
    history = getattr(rec, "history", {}) or {}
    errors: dict[str, Any] = {}
    try:
        errors["reprojection_rms"] = float(rec.reprojection_error())
    except (AttributeError, TypeError, ValueError):
        pass
    errors["reprojection_by_stage"] = _final(history, "reprojection")
    error_3d = _final(history, "error_3d")
    if error_3d:
        errors["error_3d_by_stage_m"] = error_3d
    poses = np.asarray(rec.poses)
    return {
        "kind": "reconstruction",
        "chain": None if chain is None else chain.name,
        "method": getattr(rec, "method", None),
        "converged": bool(getattr(rec, "converged", False)),
        "n_iter": int(getattr(rec, "n_iter", 0)),
        "message": getattr(rec, "message", ""),
        "n_frames": int(poses.shape[0]),
        "n_joints": int(poses.shape[1]),
        "joints": list(chain.joints) if chain is not None else None,
        "bone_lengths_m": _array_or_none(getattr(rec, "bone_lengths", None)),
        "intrinsics": (rec.intrinsics.to_dict() if hasattr(getattr(rec, "intrinsics", None), "to_dict")
                       else None),
        "timings_s": getattr(rec, "timings", {}) or {},
        "errors": errors,
        "history": history,
        "units": {"poses": "m", "bone_lengths": "m", "reprojection": "image units (px) RMS",
                  "error_3d": "m", "timings": "s"},
    }


def _fit_summary(fit: Any) -> dict[str, Any]:
    conv = np.asarray(getattr(fit, "converged", []), dtype=bool)
    res3 = _array_or_none(getattr(fit, "residual_3d", None))
    respx = _array_or_none(getattr(fit, "residual_px", None))

    def stats(x: np.ndarray | None, scale: float) -> dict[str, float] | None:
        if x is None or not np.isfinite(x).any():
            return None
        x = x[np.isfinite(x)] * scale
        return {"mean": float(x.mean()), "max": float(x.max()), "rms": float(np.sqrt((x**2).mean()))}

    q = np.asarray(fit.q)
    scale = getattr(fit, "scale", None)
    scale = float(scale) if scale is not None and np.isfinite(scale) and float(scale) > 0 else None
    from ..robot.result import joint_flags, joint_reasons

    def flagged(attr: str) -> list[str]:
        """The joint names where the fit's per-joint flags ``attr`` are set (none when it has none)."""
        return [n for n, f in zip(fit.joint_names, joint_flags(fit, attr), strict=True) if f]

    return {
        "kind": "joint_fit",
        "urdf_path": getattr(fit, "urdf_path", None),
        "n_frames": int(q.shape[0]),
        "fps": getattr(fit, "fps", None),
        "accel_std": getattr(fit, "accel_std", None),
        "jerk_std": getattr(fit, "jerk_std", None),
        "joint_names": list(fit.joint_names),
        "observable": _array_or_none(getattr(fit, "observable", None)),
        "converged_fraction": float(conv.mean()) if conv.size else None,
        "n_iter": getattr(fit, "n_iter", None),
        "message": getattr(fit, "message", ""),
        "scale": getattr(fit, "scale", None),
        # residual_3d is in the reconstruction's units (scale-free); divided by the fit's scale it is in
        # the robot's metres, so the _mm field holds millimetres on the robot
        "residual_3d_mm": stats(res3, 1000.0 / scale) if scale else None,
        "residual_3d_reconstruction_units": stats(res3, 1.0),
        "focal_px": getattr(fit, "focal_px", None),
        "focal_std_px": getattr(fit, "focal_std_px", None),
        "pinhole": getattr(fit, "camera_pose", None) is not None,
        "residual_px": stats(respx, 1.0),
        "relative_to_frame_0": flagged("relative"),
        "ambiguous": flagged("ambiguous"),
        "joint_reasons": {n: r for n, r in zip(fit.joint_names, joint_reasons(fit), strict=True) if r},
        "noise_px": (float(fit.noise_px) if getattr(fit, "noise_px", None) is not None and np.isfinite(fit.noise_px)
                     else None),
        "q_std_median": (None if getattr(fit, "q_std", None) is None else
                         {n: (float(np.nanmedian(c)) if np.isfinite(c).any() else None)
                          for n, c in zip(fit.joint_names, np.asarray(fit.q_std, float).T, strict=False)}),
        "alternatives": [{"score_noise_variances": float(a["score"]), "settled_by": a.get("settled_by")}
                         for a in getattr(fit, "alternatives", None) or []],
        "timings_s": getattr(fit, "timings", {}) or {},
        "units": {"q": "rad (revolute) or m (prismatic); continuous joints as (cos, sin)",
                  "angles": "rad (revolute, continuous) or m (prismatic), one per joint_names; joints in "
                            "relative_to_frame_0 are seen only relative to frame 0",
                  "positions": "the reconstruction's units", "residual_3d_mm": "mm on the robot (URDF scale)",
                  "residual_3d_reconstruction_units": "the reconstruction's units (scale-free)",
                  "residual_px": "px", "noise_px": "px per image coordinate", "fps": "frames per second",
                  "accel_std": "rad/s^2 (m/s^2 for prismatic joints), RMS", "jerk_std": "rad/s^3 (m/s^3), RMS",
                  "q_std": "rad (revolute, continuous) or m (prismatic), per frame and joint; NaN where held",
                  "alternatives": "other motions that fit as well; score in noise variances above the best"},
    }


_ARRAY_FIELDS = {
    "reconstruction": ("poses", "cameras", "translations", "bone_lengths", "tracks", "confidence", "method",
                       "converged", "n_iter", "message"),
    "joint_fit": ("q", "joint_names", "observable", "positions", "residual_3d", "residual_px", "converged",
                  "scale", "rotation", "translation", "cameras", "translations_2d", "urdf_path", "message",
                  "n_iter", "intrinsics", "camera_pose", "focal_px", "focal_std_px", "q_std", "noise_px",
                  "alternatives", "ambiguous", "joint_reasons", "fps", "accel_std", "jerk_std"),
}
_JSON_FIELDS = ("history", "timings")  # dicts: kept in the summary JSON inside the NPZ


def _arrays(obj: Any, kind: str) -> dict[str, np.ndarray]:
    """Every field of ``obj`` as an array (dataclass fields when it is one), the chain as names."""
    names = ([f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj)
             else list(_ARRAY_FIELDS[kind]))
    arrays = {"kind": np.array(kind)}
    for name in names:
        value = getattr(obj, name, None)
        if value is None or name == "chain" or name in _JSON_FIELDS:
            continue
        if name == "intrinsics":  # a PinholeCamera, kept as its JSON
            arrays["intrinsics_json"] = np.array(json.dumps(to_jsonable(value.to_dict()), allow_nan=False))
            continue
        if name == "camera_pose":  # (R, t): x_cam = R x_base + t
            arrays["camera_R"], arrays["camera_t"] = (np.asarray(v, float) for v in value)
            continue
        if name == "alternatives":  # a list of dicts: one stacked array per key
            if value:
                arrays["alternatives_angles"] = np.stack([np.asarray(a["angles"], float) for a in value])
                arrays["alternatives_score"] = np.array([float(a["score"]) for a in value])
                arrays["alternatives_settled_by"] = np.array([a.get("settled_by") or "" for a in value])
            continue
        if name == "urdf_path" and Path(value).exists():
            value = Path(value).resolve()  # so that the result opens from any working folder
        arr = np.asarray(str(value) if isinstance(value, os.PathLike) else value)
        if arr.dtype.kind == "O":
            continue  # nothing numeric or textual to keep
        arrays[name] = arr
    arrays.update(_chain_arrays(getattr(obj, "chain", None)))
    return arrays


def _positions_csv(f: IO[str], poses: np.ndarray, joints: Sequence[str]) -> None:
    F, J, _ = poses.shape
    w = csv.writer(f, lineterminator="\n")
    w.writerow(["frame", "joint", "x", "y", "z"])
    frames = np.repeat(np.arange(F), J)
    names = np.tile(np.asarray(joints, dtype=object), F)
    flat = poses.reshape(-1, 3)
    w.writerows(zip(frames.tolist(), names.tolist(), *(flat[:, k].tolist() for k in range(3)), strict=True))


def _angles_csv(f: IO[str], q: np.ndarray, names: Sequence[str]) -> None:
    w = csv.writer(f, lineterminator="\n")
    w.writerow(["frame", *names])
    w.writerows([[i, *row] for i, row in enumerate(q.tolist())])


def save_results(obj: Any, out: str | os.PathLike, *, overwrite: bool = False,
                 formats: Sequence[str] = ("npz", "csv", "json")) -> list[Path]:
    """Save a Reconstruction, a JointFit or a ValidationReport; return the paths written.

    ``out`` is a folder (files ``reconstruction.*``, ``joint_angles.*`` or ``validation.*`` inside
    it) or a file path whose suffix is replaced by each format's. ``formats`` picks among ``"npz"``,
    ``"csv"`` and ``"json"`` (a ValidationReport is always written as ``.json`` and a markdown
    ``.md`` table). Nothing is written if any target exists and ``overwrite`` is False.
    """
    kind = _kind(obj)
    formats = ("json", "md") if kind == "validation" else tuple(formats)
    unknown = set(formats) - {"npz", "csv", "json", "md"}
    if unknown:
        raise TrackError(f"unknown result format(s) {', '.join(sorted(unknown))}; use npz, csv, json")
    paths = dict(zip(formats, result_paths(out, kind, formats)))
    check_writable(paths.values(), overwrite)

    if kind == "validation":
        write_json(paths["json"], obj.to_dict(), overwrite=overwrite)
        with atomic_write(paths["md"], "w", overwrite) as f:
            f.write(obj.table().rstrip() + "\n")
        return list(paths.values())

    arrays = _arrays(obj, kind)
    summary = _reconstruction_summary(obj) if kind == "reconstruction" else _fit_summary(obj)
    for fmt, path in paths.items():
        if fmt == "npz":
            arrays["summary_json"] = np.array(json.dumps(to_jsonable(summary), allow_nan=False))
            with atomic_write(path, "wb", overwrite) as f:
                np.savez_compressed(f, **arrays)
        elif fmt == "json":
            write_json(path, summary, overwrite=overwrite)
        elif fmt == "csv":
            with atomic_write(path, "w", overwrite, newline="") as f:
                if kind == "reconstruction":
                    joints = arrays.get("joints", [f"joint{j}" for j in range(arrays["poses"].shape[1])])
                    _positions_csv(f, arrays["poses"], list(joints))
                else:  # one angle per joint (a continuous joint's (cos, sin) of q as radians)
                    angles = np.asarray(getattr(obj, "angles", arrays["q"]))
                    _angles_csv(f, angles, list(arrays["joint_names"]))
    return list(paths.values())


def _chain_from_arrays(data: dict[str, np.ndarray]) -> Any:
    if "joints" not in data:
        return None
    from ..chain import KinematicChain

    rigid = [tuple(p) for p in data["rigid_links"].tolist()] if "rigid_links" in data else ()
    return KinematicChain(
        data["joints"].tolist(), [tuple(p) for p in data["bones"].tolist()], data.get("rest_pose"), rigid,
        name=str(data["chain_name"]) if "chain_name" in data else None,
        metadata=json.loads(str(data["chain_metadata_json"])) if "chain_metadata_json" in data else None,
    )


def _scalar(value: np.ndarray) -> Any:
    return value.item() if value.ndim == 0 else value


def _rebuild(kind: str, data: dict[str, np.ndarray], summary: dict, chain: Any) -> Any:
    """The original dataclass (Reconstruction or JointFit) from saved fields, or None if unavailable."""
    try:
        if kind == "reconstruction":
            from ..reconstruction.pipeline import Reconstruction as cls
        else:
            from ..robot.result import JointFit as cls
    except ImportError:
        return None
    kwargs: dict[str, Any] = {}
    if "camera_R" in data:
        kwargs["camera_pose"] = (data.pop("camera_R"), data.pop("camera_t"))
    if "alternatives_angles" in data:
        kwargs["alternatives"] = [{"angles": a, "score": float(sc), "settled_by": str(by) or None}
                                  for a, sc, by in zip(data.pop("alternatives_angles"), data.pop("alternatives_score"),
                                                       data.pop("alternatives_settled_by"))]
    for f in dataclasses.fields(cls):
        if f.name in kwargs:
            continue
        if f.name == "chain":
            kwargs["chain"] = chain
        elif f.name in _JSON_FIELDS:
            kwargs[f.name] = summary.get(f.name if f.name == "history" else "timings_s", {}) or {}
        elif f.name == "intrinsics" and "intrinsics_json" in data:
            from ..cameras.pinhole import PinholeCamera

            cam = json.loads(str(data["intrinsics_json"]))
            kwargs[f.name] = PinholeCamera.from_matrix(cam["K"], cam["dist"], cam["width"], cam["height"])
        elif f.name in data:
            kwargs[f.name] = _scalar(data[f.name])
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            kwargs[f.name] = None
    for name in ("joint_names", "joint_reasons"):  # lists of str, saved as arrays
        if name in kwargs and kwargs[name] is not None:
            kwargs[name] = [str(v) for v in np.atleast_1d(kwargs[name]).tolist()]
    try:
        return cls(**kwargs)
    except (TypeError, ValueError):
        return None


def _npz_entries(path: Path) -> dict[str, np.ndarray]:
    """The arrays of an .npz by name; none for an .npy (one array, no name): not a result either."""
    loaded = np.load(path, allow_pickle=False)
    if not hasattr(loaded, "files"):
        return {}
    with loaded as npz:
        return {k: npz[k] for k in npz.files}


def load_results(path: str | os.PathLike) -> Any:
    """Read an NPZ written by :func:`save_results` back (a folder holding one NPZ works too).

    Returns the saved object, a :class:`~chainspace.reconstruction.pipeline.Reconstruction` or a
    :class:`~chainspace.robot.fit.JointFit`, with its chain rebuilt from the saved joint and bone names
    and metadata (a URDF chain's ``q_rest`` and extra frames, as JSON: lists for arrays and tuples).
    Should the class be unavailable, a namespace with the same attributes plus ``kind`` is returned.
    """
    path = Path(path)
    if path.is_dir():
        found = sorted(path.glob("*.npz"))
        if len(found) != 1:
            raise TrackError(f"{path}: expected one .npz result in the folder, found {len(found)}")
        path = found[0]
    if not path.exists():
        raise DescriptionNotFoundError(f"{path}: no such result file")
    not_a_result = f"{path}: not a chainspace result file (the .npz that reconstruct or fit writes)"
    try:
        data = _npz_entries(path)
    except ValueError:  # neither .npy nor .npz: numpy's text is about pickles, which would mislead
        raise TrackError(not_a_result) from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise TrackError(f"{not_a_result}; it cannot be read: {exc}") from None
    if "kind" not in data:
        raise TrackError(not_a_result)  # an .npy, or an .npz of other arrays
    summary = json.loads(str(data.pop("summary_json"))) if "summary_json" in data else {}
    kind = str(data.pop("kind"))
    chain = _chain_from_arrays(data)
    for k in ("joints", "bones", "rigid_links", "rest_pose", "chain_name", "chain_metadata_json"):
        data.pop(k, None)
    obj = _rebuild(kind, data, summary, chain)
    if obj is not None:
        return obj
    ns = SimpleNamespace(kind=kind, chain=chain, summary=summary, history=summary.get("history", {}) or {},
                         timings=summary.get("timings_s", {}) or {})
    for k in _ARRAY_FIELDS[kind]:
        setattr(ns, k, _scalar(data[k]) if k in data else None)
    if kind == "joint_fit":
        ns.joint_names = list(np.atleast_1d(ns.joint_names).tolist())
        ns.joint_reasons = [] if ns.joint_reasons is None else [str(v) for v in np.atleast_1d(ns.joint_reasons)]
    return ns

