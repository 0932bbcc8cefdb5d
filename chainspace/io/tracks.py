"""2D tracks in and out: the file formats people have, mapped onto a chain's joints by name.

Tracks are (F, J, 2) arrays of image points (pixels, x right, y down as the file gives them), NaN where
a point was not seen; confidences are (F, J) weights in [0, 1]. A point with confidence 0 is kept
(a stage weights it out); a point absent from the file is NaN with confidence 0.

Formats (``format=`` or guessed from the path):

``csv``
    Long table with header ``frame,joint,x,y[,confidence]``, one row per point; frames are 0-based
    indices, absent rows and empty ``x``/``y`` cells are missing points.
``npy``
    (F, J, 2) array, or (F, J, 3) with the confidence as third channel. Carries no names: with a chain
    the joints are taken to be in the chain's order.
``npz``
    ``tracks`` (F, J, 2), ``names`` (J,), optional ``confidence`` (F, J).
``coco``
    COCO keypoint JSON: a list of annotations (or a dict with ``"annotations"``), each with
    ``"keypoints"`` ``[x, y, v] * 17`` and ``"frame"`` or ``"image_id"``. Integer ``v`` are COCO
    visibility flags (0: not labelled, the point is missing); float ``v`` are detector scores, used as
    confidences. Names: :data:`COCO17`.
``openpose``
    A folder of OpenPose ``*_keypoints.json`` files, one per frame in file-name order, reading
    ``people[0].pose_keypoints_2d`` ``[x, y, c] * K``; K = 25 is :data:`BODY_25`, K = 18 is
    :data:`COCO18`. ``x = y = c = 0`` is a missing point.
``mediapipe``
    JSON of MediaPipe pose landmarks: a list of frames (or ``{"frames": [...]}``), each a list of 33
    landmarks ``{"x", "y", "visibility"}`` (or ``{"landmarks": [...]}``; ``null`` for no detection)
    with x, y normalised to the image; ``image_size=(width, height)`` (or ``image_width`` and
    ``image_height`` in the file) converts them to pixels. Names: :data:`MEDIAPIPE33`.

With ``chain=``, the file's joints are mapped onto the chain by name: exact names first, then the
:data:`ALIASES` table (OpenPose ``RShoulder`` -> ``right_shoulder``, ``MidHip`` -> ``pelvis``, ...),
then the midpoints in :data:`DERIVED` (a human17 ``pelvis`` from the two hips when a detector has
none). Chain joints still not found are NaN.
"""

from __future__ import annotations

import csv
import difflib
import json
import math
import os
import re
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DescriptionNotFoundError, TrackError, located
from .results import atomic_write, check_writable

__all__ = ["load_tracks", "save_tracks", "map_to_chain", "FORMATS", "COCO17", "COCO18", "BODY_25",
           "MEDIAPIPE33", "ALIASES", "DERIVED"]

FORMATS = ("csv", "npy", "npz", "coco", "openpose", "mediapipe")

COCO17 = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
          "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
          "right_knee", "left_ankle", "right_ankle")
COCO18 = ("Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "RHip", "RKnee",
          "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar")
BODY_25 = ("Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip", "RHip",
           "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar", "LBigToe",
           "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel")
MEDIAPIPE33 = ("nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
               "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
               "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
               "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
               "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
               "right_heel", "left_foot_index", "right_foot_index")


def _openpose_alias(name: str) -> str:
    side = {"L": "left_", "R": "right_"}[name[0]]
    rest = re.sub(r"(?<!^)([A-Z])", r"_\1", name[1:]).lower()
    return side + rest


#: Detector joint names -> the canonical names of the shipped human17 and coco17 chains.
#: OpenPose's "Neck" is the mid-shoulder point (human17 "thorax"); a detector's nose stands in for the
#: human17 "head" (an approximation: detectors have no head-top point).
ALIASES: dict[str, str] = {
    **{n: _openpose_alias(n) for n in BODY_25 if n[0] in "LR" and n[1].isupper()},
    "Nose": "nose", "Neck": "thorax", "MidHip": "pelvis", "nose": "head",
    "left_foot_index": "left_big_toe", "right_foot_index": "right_big_toe",
}
#: Chain joints a detector lacks, built as the midpoint of joints it has (canonical names).
DERIVED: dict[str, tuple[str, ...]] = {
    "pelvis": ("left_hip", "right_hip"),
    "thorax": ("left_shoulder", "right_shoulder"),
    "spine": ("pelvis", "thorax"),
    "neck": ("thorax", "head"),
}

_LAYOUTS = {"coco": (COCO17,), "openpose": (BODY_25, COCO18), "mediapipe": (MEDIAPIPE33,)}
_DETECTOR_NAMES = frozenset(COCO17 + COCO18 + BODY_25 + MEDIAPIPE33)


# ---------------------------------------------------------------------------------------- checks
def _as_tracks(tracks: Any, confidence: Any, names: Sequence[str], source: object = None
               ) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """Validate and normalise (tracks, confidence, names); raise TrackError naming frame and joint."""
    try:
        P = np.array(tracks, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrackError(located(f"tracks are not numeric: {exc}", source)) from None
    if P.ndim != 3 or P.shape[2] != 2:
        raise TrackError(located(f"tracks have shape {P.shape}, expected (frames, joints, 2)", source))
    if P.shape[0] == 0 or P.shape[1] == 0:
        raise TrackError(located(f"tracks are empty (shape {P.shape})", source))
    names = [str(n) for n in names]
    if len(names) != P.shape[1]:
        raise TrackError(located(f"{len(names)} joint names for {P.shape[1]} joints in the tracks", source))
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise TrackError(located(f"joint names given twice: {', '.join(dup)}", source))
    _check_finite(P, names, "track", source)
    if np.isnan(P).any(axis=2).any():  # a point is missing when either coordinate is
        P[np.isnan(P).any(axis=2)] = np.nan
    if np.isnan(P).all():
        raise TrackError(located("the tracks hold no point: every value is missing", source))
    if confidence is None:
        return P, None, names
    try:
        c = np.array(confidence, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrackError(located(f"confidences are not numeric: {exc}", source)) from None
    if c.shape != P.shape[:2]:
        raise TrackError(located(f"confidence has shape {c.shape}, expected {P.shape[:2]}", source))
    missing = np.isnan(P[..., 0])
    c[missing & np.isnan(c)] = 0.0
    _check_finite(c[..., None], names, "confidence", source)
    bad = np.argwhere(np.isnan(c) | (c < 0) | (c > 1))
    if len(bad):
        f, j = bad[0]
        raise TrackError(located(
            f"confidence {c[f, j]} of joint {names[j]!r} in frame {f} is not a weight in [0, 1]", source))
    return P, c, names


def _check_finite(a: np.ndarray, names: Sequence[str], what: str, source: object) -> None:
    bad = np.argwhere(np.isinf(a))
    if len(bad):
        f, j = bad[0][:2]
        raise TrackError(located(f"{what} of joint {names[j]!r} in frame {f} is infinite", source))


def _aliases(name: str) -> list[str]:
    """``name`` followed by what it stands for through :data:`ALIASES` (``Nose`` -> nose -> head)."""
    out = [name]
    while out[-1] in ALIASES and ALIASES[out[-1]] not in out:
        out.append(ALIASES[out[-1]])
    return out


def _points(n: int) -> str:
    return f"{n} tracked point{'' if n == 1 else 's'}"


def _listed(names: Sequence[str]) -> str:
    return ", ".join(names[:6]) + (", ..." if len(names) > 6 else "")


def _left_out(unused: list[str], chain: Any, found: list[str]) -> str:
    """Why tracked points are left out: the chain is a selection that dropped them (links=, subset),
    or the chain has no such point (a tool marker, or a typo: then the likely meant joint)."""
    dropped = set(chain.metadata.get("left_out", ()))
    unselected = [n for n in unused if n in dropped]
    unknown = [n for n in unused if n not in dropped]
    parts = []
    if unselected:
        parts.append(f"{_points(len(unselected))} not selected for the chain {chain.name} (links=, chain.subset), "
                     f"left out: {_listed(unselected)}")
    if unknown:
        missing = [j for j in chain.joints if j not in found]  # a misspelt name's joint has no track
        meant = {n: close[0] for n in unknown if (close := difflib.get_close_matches(n, missing, n=1))}
        pairs = [f"{m!r}" if len(unknown) == 1 else f"{m!r} for {n!r}" for n, m in meant.items()]
        hint = f"did you mean {', '.join(pairs)}? " if meant else ""
        parts.append(f"{_points(len(unknown))} not in the chain {chain.name}, left out: {_listed(unknown)} "
                     f"({hint}a point on a robot link is added as an extra frame: extra_frames=)")
    return "; ".join(parts)


def map_to_chain(tracks: np.ndarray, confidence: np.ndarray | None, names: Sequence[str], chain: Any,
                 source: object = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Rearrange (F, N, 2) tracks named ``names`` into ``chain``'s joint order (NaN where unseen).

    Exact names first, then :data:`ALIASES`, then the midpoints of :data:`DERIVED`. Raises
    :class:`TrackError` when no name matches.
    """
    names = list(names)
    index: dict[str, int] = {}
    for i, n in enumerate(names):  # aliases, overridden by exact names below
        for a in _aliases(n)[1:]:
            index.setdefault(a, i)
    index.update({n: i for i, n in enumerate(names)})
    c = np.ones(tracks.shape[:2]) if confidence is None else confidence
    cols_p: dict[str, np.ndarray] = {n: tracks[:, i] for n, i in index.items()}
    cols_c: dict[str, np.ndarray] = {n: c[:, i] for n, i in index.items()}
    for target, sources in DERIVED.items():  # in dependency order: spine after pelvis and thorax
        if target not in cols_p and all(s in cols_p for s in sources):
            cols_p[target] = np.mean([cols_p[s] for s in sources], axis=0)
            cols_c[target] = np.min([cols_c[s] for s in sources], axis=0)
    found = [j for j in chain.joints if j in cols_p]
    # a named point that no chain joint takes and no detector has (a tool marker, a typo) is left out:
    # say so, since its column is then lost (detectors' extra points, eyes and ears, are left out silently)
    unused = [n for n in names if n not in _DETECTOR_NAMES and not any(a in chain.joints for a in _aliases(n))
              and not any(n in srcs and t in chain.joints for t, srcs in DERIVED.items())]
    if found and unused:
        warnings.warn(located(_left_out(unused, chain, found), source), UserWarning, stacklevel=3)
    if not found:
        raise TrackError(located(
            f"no joint name of the tracks matches the chain {chain.name} (tracks have "
            f"{', '.join(names[:6])}{', ...' if len(names) > 6 else ''}; the chain has "
            f"{', '.join(chain.joints[:6])}{', ...' if chain.n_joints > 6 else ''})", source))
    P = chain.reorder(np.stack([cols_p[j] for j in found], axis=1), found, axis=-2)
    if confidence is None:
        return P, None
    C = chain.reorder(np.stack([cols_c[j] for j in found], axis=1), found, axis=-1, fill=0.0)
    return P, C


# ---------------------------------------------------------------------------------------- guessing
def _guess_format(path: Path) -> str:
    if path.is_dir():
        if any(path.glob("*_keypoints.json")):
            return "openpose"
        raise TrackError(f"{path}: a folder of tracks must hold OpenPose *_keypoints.json files")
    ext = path.suffix.lower()
    if ext in (".csv", ".npy", ".npz"):
        return ext[1:]
    if ext == ".json":
        data = _read_json(path)
        if isinstance(data, dict) and "people" in data:
            return "openpose"
        if isinstance(data, dict) and ("annotations" in data or "keypoints" in data):
            return "coco"
        if isinstance(data, list) and data and isinstance(data[0], dict) and "keypoints" in data[0]:
            return "coco"
        return "mediapipe"
    raise TrackError(f"{path}: unknown track format {ext or '(no extension)'!r}; pass format= one of "
                     f"{', '.join(FORMATS)}")


def _read_json(path: Path) -> Any:
    text = path.read_text(encoding="utf-8")
    if not text.strip():
        raise TrackError(f"{path}: the file is empty")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise TrackError(located(f"malformed JSON: {exc.msg} (column {exc.colno})", path, exc.lineno)) from None
    except RecursionError:
        raise TrackError(f"{path}: JSON nested too deeply to be keypoints") from None


# ---------------------------------------------------------------------------------------- readers
def _read_csv(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    rows = [(i + 1, r) for i, r in enumerate(rows) if any(cell.strip() for cell in r)]
    if not rows:
        raise TrackError(f"{path}: the file is empty")
    header = [h.strip().lower() for h in rows[0][1]]
    required = ["frame", "joint", "x", "y"]
    missing = [h for h in required if h not in header]
    extra = [h for h in header if h not in required + ["confidence"]]
    if missing or extra or len(set(header)) != len(header):
        raise TrackError(located(
            f"wrong columns {','.join(header)}: expected frame,joint,x,y[,confidence]", path, rows[0][0]))
    col = {h: i for i, h in enumerate(header)}
    has_conf = "confidence" in col
    if len(rows) < 2:
        raise TrackError(f"{path}: the file has a header and no data rows")
    frames, joints, values = [], [], []
    for line, r in rows[1:]:
        if len(r) != len(header):
            raise TrackError(located(f"expected {len(header)} fields, found {len(r)}", path, line))
        try:
            frame = int(r[col["frame"]])
            vals = [float(r[col[k]]) if r[col[k]].strip() else math.nan
                    for k in ("x", "y", "confidence") if k in col]
        except ValueError as exc:
            raise TrackError(located(f"malformed row {','.join(r)!r}: {exc}", path, line)) from None
        if frame < 0:
            raise TrackError(located(f"negative frame {frame}", path, line))
        if any(math.isinf(v) for v in vals):
            raise TrackError(located("infinite value", path, line))
        name = r[col["joint"]].strip()
        if not name:
            raise TrackError(located("empty joint name", path, line))
        frames.append(frame)
        joints.append(name)
        values.append(vals + [line])
    names = list(dict.fromkeys(joints))
    j_of = {n: j for j, n in enumerate(names)}
    F = _frame_count(max(frames), len(frames), path)
    P = np.full((F, len(names), 2), np.nan)
    conf = np.zeros((F, len(names))) if has_conf else None
    seen = np.zeros((F, len(names)), dtype=int)
    for frame, name, vals in zip(frames, joints, values, strict=True):
        j = j_of[name]
        if seen[frame, j]:
            raise TrackError(located(f"joint {name!r} in frame {frame} appears twice (first on line "
                                     f"{seen[frame, j]})", path, vals[-1]))
        seen[frame, j] = vals[-1]
        P[frame, j] = vals[:2]
        if has_conf:
            conf[frame, j] = vals[2]
    _check_cut_short(seen, names, path)
    return P, conf, names


def _check_cut_short(seen: np.ndarray, names: list[str], path: Path) -> None:
    """A file cut at a line boundary: every frame has a row per joint but the last, which has only the
    first few joints' rows and ends the file. Its missing points would pass for unseen ones."""
    F, J = seen.shape
    rows = seen > 0
    if F < 2 or J < 2 or not rows[:-1].all():
        return
    have = np.flatnonzero(rows[-1])
    if len(have) == 0 or len(have) == J:
        return
    last_line = int(seen.max())
    if int(seen[-1].max()) != last_line:  # the partial frame is not where the file ends
        return
    lost = [names[j] for j in np.flatnonzero(~rows[-1])]
    raise TrackError(located(
        f"the last frame ({F - 1}) has rows for only {len(have)} of the {J} joints (no row for "
        f"{', '.join(lost[:4])}{', ...' if len(lost) > 4 else ''}), while every other frame has all: "
        f"the file looks cut short; complete or remove frame {F - 1}", path, last_line))


def _frame_count(last: int, n_rows: int, path: Path) -> int:
    """Frames 0..last; refuses numbering so sparse that it would be mostly empty memory."""
    if last + 1 > 100 * n_rows + 10_000:
        raise TrackError(f"{path}: frame numbers reach {last} for only {n_rows} rows; frames are 0-based "
                         "indices of consecutive video frames")
    return last + 1


def _read_npy(path: Path, chain: Any) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise TrackError(f"{path}: not a readable .npy array ({exc})") from None
    if a.ndim != 3 or a.shape[2] not in (2, 3):
        raise TrackError(f"{path}: array has shape {a.shape}, expected (frames, joints, 2 or 3)")
    J = a.shape[1]
    if chain is not None and J != chain.n_joints:
        raise TrackError(f"{path}: {J} joints in the array but the chain {chain.name} has {chain.n_joints}; "
                         "a .npy carries no joint names, so it must be in the chain's order (use .npz "
                         "with names, or CSV)")
    names = list(chain.joints) if chain is not None else [f"joint{j}" for j in range(J)]
    return a[..., :2], (a[..., 2] if a.shape[2] == 3 else None), names


def _read_npz(path: Path, chain: Any = None) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise TrackError(f"{path}: not a readable .npz archive ({exc})") from None
    except zipfile.BadZipFile as exc:
        raise TrackError(f"{path}: not a readable .npz archive ({exc})") from None
    if "tracks" not in data:
        raise TrackError(f"{path}: no 'tracks' array (found {', '.join(data) or 'nothing'})")
    P = data["tracks"]
    J = P.shape[1] if P.ndim > 1 else 0
    if "names" not in data:
        # names under another key would be ignored and the joints read in array order: refuse instead
        named = [k for k, v in data.items() if k not in ("tracks", "confidence") and v.ndim == 1 and len(v) == J
                 and v.dtype.kind in "US"]
        if named:
            raise TrackError(f"{path}: no 'names' array, but {named[0]!r} holds {J} strings: if those are the "
                             "joints' names, store them as 'names' (only that array names the joints)")
    if "names" not in data and chain is not None and P.ndim == 3:
        # no names: like a .npy, the joints must be the chain's, in its order; their count is checked
        if J != chain.n_joints:
            raise TrackError(f"{path}: {J} joints in the 'tracks' array but the chain {chain.name} has "
                             f"{chain.n_joints}; without a 'names' array the joints must be the chain's, "
                             "in its order")
        return P, data.get("confidence"), list(chain.joints)
    names = data["names"].tolist() if "names" in data else [f"joint{j}" for j in range(J)]
    return P, data.get("confidence"), names


def _pick_annotation(anns: list[dict]) -> dict:
    return max(anns, key=lambda a: a.get("score", 1.0) if isinstance(a.get("score", 1.0), (int, float)) else 0)


def _triplets(values: Any, k: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """[x, y, v] * k -> (k, 2) points (NaN where x = y = v = 0, or v = 0 for int flags), (k,) v."""
    if not isinstance(values, list) or len(values) != 3 * k:
        n = len(values) if isinstance(values, list) else type(values).__name__
        raise TrackError(f"{where}: expected {3 * k} keypoint values ([x, y, v] * {k}), found {n}")
    try:
        a = np.array(values, dtype=float).reshape(k, 3)
    except (TypeError, ValueError):
        raise TrackError(f"{where}: keypoints are not all numbers") from None
    absent = (a == 0).all(axis=1)
    pts = a[:, :2].copy()
    pts[absent] = np.nan
    return pts, a[:, 2]


def _read_coco(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    data = _read_json(path)
    anns = data.get("annotations", [data] if "keypoints" in data else None) if isinstance(data, dict) else data
    if not isinstance(anns, list) or not anns:
        raise TrackError(f"{path}: expected a list of COCO keypoint annotations")
    by_frame: dict[int, list[dict]] = {}
    use_frame = all(isinstance(a, dict) and "frame" in a for a in anns)
    for i, a in enumerate(anns):
        key = a.get("frame") if use_frame else a.get("image_id", i) if isinstance(a, dict) else None
        if not isinstance(a, dict) or not isinstance(key, int) or (use_frame and key < 0):
            raise TrackError(f"{path}: annotation {i} has no integer 'frame' or 'image_id'")
        by_frame.setdefault(key, []).append(a)
    keys = sorted(by_frame)
    index = {k: k for k in keys} if use_frame else {k: i for i, k in enumerate(keys)}
    F = _frame_count(max(keys), len(anns), path) if use_frame else len(keys)
    P = np.full((F, 17, 2), np.nan)
    V = np.zeros((F, 17))
    flags = True
    for k in keys:
        a = _pick_annotation(by_frame[k])
        raw = a.get("keypoints")
        pts, v = _triplets(raw, 17, f"{path}: annotation of frame {k}")
        flags &= all(isinstance(x, int) for x in raw[2::3])
        P[index[k]], V[index[k]] = pts, v
    if flags:  # COCO visibility flags: 0 is "not labelled", whatever x and y say
        P[V == 0] = np.nan
        return P, None, list(COCO17)
    return P, V, list(COCO17)


def _read_openpose(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    files = sorted(path.glob("*_keypoints.json")) if path.is_dir() else [path]
    if not files:
        raise TrackError(f"{path}: no *_keypoints.json files in the folder")
    frames: list[tuple[np.ndarray, np.ndarray] | None] = []
    k = None
    for f in files:
        data = _read_json(f)
        people = data.get("people") if isinstance(data, dict) else None
        if not isinstance(people, list):
            raise TrackError(f"{f}: no 'people' list (not an OpenPose keypoint file)")
        if not people:
            frames.append(None)
            continue
        raw = people[0].get("pose_keypoints_2d") if isinstance(people[0], dict) else None
        n = len(raw) // 3 if isinstance(raw, list) else -1
        if k is None and n in (25, 18):
            k = n
        if n != k:
            raise TrackError(f"{f}: pose_keypoints_2d has {len(raw) if isinstance(raw, list) else 'no'} "
                             f"values; expected 75 (BODY_25) or 54 (COCO-18), the same in every file")
        frames.append(_triplets(raw, k, str(f)))
    if k is None:
        raise TrackError(f"{path}: no person detected in any of the {len(files)} files")
    P = np.full((len(files), k, 2), np.nan)
    C = np.zeros((len(files), k))
    for i, fr in enumerate(frames):
        if fr is not None:
            P[i], C[i] = fr
    return P, C, list(BODY_25 if k == 25 else COCO18)


def _landmark_list(frame: Any, where: str) -> list | None:
    if frame is None or frame == [] or frame == {}:
        return None
    if isinstance(frame, dict):
        frame = frame.get("landmarks", frame.get("pose_landmarks"))
        if frame is None or frame == []:
            return None
    if isinstance(frame, list) and frame and isinstance(frame[0], list):  # one list per detected pose
        frame = frame[0]
    if not isinstance(frame, list) or len(frame) != 33 or not all(isinstance(p, dict) for p in frame):
        raise TrackError(f"{where}: expected 33 pose landmarks {{x, y, visibility}}")
    return frame


def _read_mediapipe(path: Path, image_size: Sequence[float] | None
                    ) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    data = _read_json(path)
    frames = data.get("frames") if isinstance(data, dict) else data
    if not isinstance(frames, list) or not frames:
        raise TrackError(f"{path}: expected a list of frames of MediaPipe pose landmarks")
    if image_size is None and isinstance(data, dict) and "image_width" in data and "image_height" in data:
        image_size = (data["image_width"], data["image_height"])
    if image_size is None:
        raise TrackError(f"{path}: MediaPipe landmarks are normalised to the image; give "
                         "image_size=(width, height) in pixels (--image-size W H)")
    try:
        size = np.array(image_size, dtype=float).reshape(2)
    except (TypeError, ValueError):
        raise TrackError(f"{path}: image size {image_size!r} is not (width, height)") from None
    if not (np.isfinite(size).all() and (size > 0).all()):
        raise TrackError(f"{path}: image size {image_size!r} must be two positive numbers")
    P = np.full((len(frames), 33, 2), np.nan)
    C = np.zeros((len(frames), 33))
    for i, fr in enumerate(frames):
        lms = _landmark_list(fr, f"{path}: frame {i}")
        if lms is None:
            continue
        try:
            P[i] = [[float(p["x"]), float(p["y"])] for p in lms]
            C[i] = [float(p.get("visibility", 1.0)) for p in lms]
        except (KeyError, TypeError, ValueError):
            raise TrackError(f"{path}: frame {i}: a landmark lacks numeric x and y") from None
    P[(P == 0).all(axis=2) & (C == 0)] = np.nan  # how a landmark without data is written
    return P * size, np.clip(C, 0.0, 1.0), list(MEDIAPIPE33)


def load_tracks(path: str | os.PathLike, chain: Any = None, format: str | None = None, *,
                image_size: Sequence[float] | None = None
                ) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """Read 2D tracks from ``path``.

    Returns ``(tracks (F, J, 2) px, confidence (F, J) in [0, 1] or None, names)``. With ``chain``,
    the joints are mapped onto the chain's (see :func:`map_to_chain`) and ``names`` is
    ``chain.joints``. ``format`` is one of :data:`FORMATS` (guessed from the path when None);
    ``image_size=(width, height)`` in pixels converts normalised MediaPipe landmarks. Raises
    :class:`TrackError` (file:line where known) for empty, malformed or non-finite input.
    """
    if format is not None and not isinstance(format, str):
        raise TrackError(f"format must be a string among {', '.join(FORMATS)}, not {format!r}")
    path = Path(path)
    if not path.exists():
        raise DescriptionNotFoundError(f"{path}: no such track file or folder")
    if path.is_file() and path.stat().st_size == 0:
        raise TrackError(f"{path}: the file is empty")
    fmt = (format or _guess_format(path)).lower()
    if fmt not in FORMATS:
        raise TrackError(f"unknown track format {format!r}; use one of {', '.join(FORMATS)}")
    try:
        if fmt == "csv":
            P, C, names = _read_csv(path)
        elif fmt == "npy":
            P, C, names = _read_npy(path, chain)
        elif fmt == "npz":
            P, C, names = _read_npz(path, chain)
        elif fmt == "coco":
            P, C, names = _read_coco(path)
        elif fmt == "openpose":
            P, C, names = _read_openpose(path)
        else:
            P, C, names = _read_mediapipe(path, image_size)
    except UnicodeDecodeError:
        raise TrackError(f"{path}: not a text file (is the format {fmt!r} right?)") from None
    P, C, names = _as_tracks(P, C, names, path)
    if chain is not None:
        P, C = map_to_chain(P, C, names, chain, path)
        names = list(chain.joints)
    return P, C, names


# ---------------------------------------------------------------------------------------- writers
def _to_layout(P: np.ndarray, C: np.ndarray | None, names: list[str], fmt: str
               ) -> tuple[np.ndarray, np.ndarray | None, tuple[str, ...]]:
    """Tracks in the joint layout of ``fmt`` (COCO-17, BODY_25/COCO-18, MediaPipe-33), NaN-filled."""
    for layout in _LAYOUTS[fmt]:
        if list(layout) == names:
            return P, C, layout
    layout = _LAYOUTS[fmt][0]
    canon: dict[str, int] = {}
    for k, n in enumerate(layout):
        for a in _aliases(n)[1:]:
            canon.setdefault(a, k)
    canon.update({n: k for k, n in enumerate(layout)})
    used: dict[int, int] = {}
    for i, n in enumerate(names):
        k = next((canon[a] for a in _aliases(n) if a in canon), None)
        if k is not None and k not in used.values():
            used[i] = k
    if not used:
        raise TrackError(f"none of the joint names ({', '.join(names[:5])}, ...) is a {fmt} keypoint "
                         f"({', '.join(layout[:5])}, ...)")
    out = np.full((P.shape[0], len(layout), 2), np.nan)
    out_c = np.zeros((P.shape[0], len(layout)))
    src, dst = list(used), list(used.values())
    out[:, dst] = P[:, src]
    out_c[:, dst] = 1.0 if C is None else C[:, src]
    return out, (None if C is None else out_c), layout


def _write_csv(path: Path, P: np.ndarray, C: np.ndarray | None, names: list[str], overwrite: bool) -> None:
    F, J, _ = P.shape
    with atomic_write(path, "w", overwrite, newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["frame", "joint", "x", "y"] + (["confidence"] if C is not None else []))
        for i in range(F):
            for j in range(J):
                xy = ["", ""] if np.isnan(P[i, j, 0]) else [repr(float(P[i, j, 0])), repr(float(P[i, j, 1]))]
                w.writerow([i, names[j], *xy] + ([repr(float(C[i, j]))] if C is not None else []))


def _save_npy(path: Path, P: np.ndarray, C: np.ndarray | None, overwrite: bool) -> None:
    a = P if C is None else np.concatenate([P, C[..., None]], axis=2)
    with atomic_write(path, "wb", overwrite) as f:
        np.save(f, a)


def _save_npz(path: Path, P: np.ndarray, C: np.ndarray | None, names: list[str], overwrite: bool) -> None:
    arrays = {"tracks": P, "names": np.array(names, dtype=str)}
    if C is not None:
        arrays["confidence"] = C
    with atomic_write(path, "wb", overwrite) as f:
        np.savez_compressed(f, **arrays)


def _keypoint_list(P: np.ndarray, v: np.ndarray, flags: bool) -> list:
    out = []
    for (x, y), vi in zip(P.tolist(), v.tolist(), strict=True):
        if math.isnan(x):
            out += [0, 0, 0] if flags else [0.0, 0.0, 0.0]
        else:
            out += [x, y, int(vi) if flags else float(vi)]
    return out


def _save_coco(path: Path, P: np.ndarray, C: np.ndarray | None, overwrite: bool) -> None:
    flags = C is None
    V = np.where(np.isnan(P[..., 0]), 0, 2) if flags else C
    anns = [{"image_id": i, "frame": i, "category_id": 1, "num_keypoints": int((~np.isnan(P[i, :, 0])).sum()),
             "keypoints": _keypoint_list(P[i], V[i], flags)} for i in range(P.shape[0])]
    with atomic_write(path, "w", overwrite) as f:
        json.dump(anns, f)


def _save_openpose(path: Path, P: np.ndarray, C: np.ndarray | None, overwrite: bool) -> None:
    V = np.where(np.isnan(P[..., 0]), 0.0, 1.0) if C is None else C
    targets = [path / f"{path.name}_{i:012d}_keypoints.json" for i in range(P.shape[0])]
    if path.exists() and not path.is_dir():
        raise TrackError(f"{path}: OpenPose tracks are written to a folder, and this is a file")
    check_writable(targets, overwrite)
    for i, target in enumerate(targets):
        doc = {"version": 1.3, "people": [{"person_id": [-1],
                                           "pose_keypoints_2d": _keypoint_list(P[i], V[i], False)}]}
        with atomic_write(target, "w", overwrite) as f:
            json.dump(doc, f)


def _save_mediapipe(path: Path, P: np.ndarray, C: np.ndarray | None, image_size: Sequence[float] | None,
                    overwrite: bool) -> None:
    if image_size is None:  # smallest whole-pixel frame holding every point
        image_size = np.ceil(np.nanmax(P.reshape(-1, 2), axis=0) + 1).tolist()
    w, h = (float(s) for s in image_size)
    V = np.where(np.isnan(P[..., 0]), 0.0, 1.0) if C is None else C
    frames = []
    for i in range(P.shape[0]):
        if np.isnan(P[i, :, 0]).all():
            frames.append(None)
            continue
        frames.append({"landmarks": [
            {"x": (x / w if not math.isnan(x) else 0.0), "y": (y / h if not math.isnan(y) else 0.0), "z": 0.0,
             "visibility": (float(v) if not math.isnan(x) else 0.0)}
            for (x, y), v in zip(P[i].tolist(), V[i].tolist(), strict=True)]})
    with atomic_write(path, "w", overwrite) as f:
        json.dump({"image_width": w, "image_height": h, "frames": frames}, f)


def save_tracks(path: str | os.PathLike, tracks: Any, names: Sequence[str], confidence: Any = None,
                format: str | None = None, overwrite: bool = False, *,
                image_size: Sequence[float] | None = None) -> Path:
    """Write tracks (F, J, 2) px named ``names`` (and confidences (F, J)) in ``format``.

    ``format`` is one of :data:`FORMATS`, guessed from the suffix (``.csv``, ``.npy``, ``.npz``,
    ``.json`` -> ``coco``; a path without suffix -> an ``openpose`` folder) when None. COCO, OpenPose
    and MediaPipe files have a fixed joint layout: joints are mapped onto it by name (aliases
    allowed), and layout joints without data are written as missing. MediaPipe landmarks are
    normalised by ``image_size=(width, height)`` (default: the extent of the points), which is
    stored in the file. Writes atomically; refuses to replace files unless ``overwrite``.
    """
    if format is not None and not isinstance(format, str):
        raise TrackError(f"format must be a string among {', '.join(FORMATS)}, not {format!r}")
    if isinstance(names, str):
        raise TrackError("names must be a sequence of joint names, not one string")
    path = Path(path)
    P, C, names = _as_tracks(tracks, confidence, list(names))
    fmt = format.lower() if format else {".csv": "csv", ".npy": "npy", ".npz": "npz", ".json": "coco",
                                          "": "openpose"}.get(path.suffix.lower())
    if fmt not in FORMATS:
        raise TrackError(f"cannot tell the track format of {path} (format={format!r}); use one of "
                         f"{', '.join(FORMATS)}")
    if fmt == "csv":
        _write_csv(path, P, C, names, overwrite)
    elif fmt == "npy":
        _save_npy(path, P, C, overwrite)
    elif fmt == "npz":
        _save_npz(path, P, C, names, overwrite)
    else:
        P, C, _ = _to_layout(P, C, names, fmt)
        if fmt == "coco":
            _save_coco(path, P, C, overwrite)
        elif fmt == "openpose":
            _save_openpose(path, P, C, overwrite)
        else:
            _save_mediapipe(path, P, C, image_size, overwrite)
    return path
