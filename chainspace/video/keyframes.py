"""Key frames: where the user says the chain's points are, in some frames of a video.

The file is JSON keyed by frame index (0-based), then by point name, with pixel positions (image x to
the right, y down; the centre of the top-left pixel is (0, 0))::

    {"0": {"link_2": [412.5, 310.0], "tool": [500.0, 280.25]},
     "120": {"link_2": [430.0, 305.5], "tool": null}}

``null`` says the point is not visible from that frame on (until a later key frame gives it again).
:func:`load_keyframes` reads and checks it; ``chainspace pick`` writes it from clicks on a frame.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import VideoError, located

__all__ = ["Keyframes", "load_keyframes", "save_keyframes", "point_names"]

#: frame index -> point name -> (x, y) px, or None where the point is hidden
Keyframes = dict[int, dict[str, "tuple[float, float] | None"]]


def _frame_index(key: Any, source: object) -> int:
    text = str(key).strip()
    if isinstance(key, bool) or not text.isdigit():
        raise VideoError(located(f"key frame {key!r} is not a frame index (an integer >= 0, as a string "
                                 "in JSON: \"120\")", source))
    return int(text)


def _point(value: Any, frame: int, name: str, source: object,
           image_size: Sequence[float] | None) -> tuple[float, float] | None:
    if value is None:
        return None
    where = f"key frame {frame}, point {name!r}"
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)):
        raise VideoError(located(f"{where}: expected [x, y] in pixels (or null), not {value!r}", source))
    x, y = float(value[0]), float(value[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise VideoError(located(f"{where}: [{x}, {y}] is not finite", source))
    if image_size is not None:
        w, h = image_size
        # pixel centres run from 0 to w - 1; a click on the outer half of an edge pixel is still inside
        if not (-0.5 <= x <= w - 0.5 and -0.5 <= y <= h - 0.5):
            raise VideoError(located(f"{where}: [{x:g}, {y:g}] is outside the {w}x{h} px image", source))
    return x, y


def load_keyframes(source: str | os.PathLike | Mapping[Any, Any], *, names: Sequence[str] | None = None,
                   image_size: Sequence[int] | None = None, frame_count: int | None = None) -> Keyframes:
    """Read and check key frames from a JSON file or an already-parsed mapping.

    Parameters
    ----------
    source
        Path of the JSON file, or the mapping itself (frame index -> point name -> [x, y] px or None).
    names
        The point names allowed (a chain's joints); a name outside them is an error.
    image_size
        ``(width, height)`` px: a point outside the image is an error.
    frame_count
        Frames of the video: a key frame past its end is an error.

    Returns
    -------
    dict
        ``{frame: {name: (x, y) or None}}`` ordered by frame.

    Raises
    ------
    VideoError
        Naming the file, the key frame and the point.
    """
    where: object = None
    if isinstance(source, Mapping):
        data: Any = source
    else:
        where = Path(source)
        if not where.exists():
            raise VideoError(f"{where}: no such key-frame file")
        try:
            data = json.loads(where.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            line = getattr(exc, "lineno", None)
            raise VideoError(located(f"not valid JSON ({getattr(exc, 'msg', exc)})", where, line)) from None
    if not isinstance(data, Mapping) or not data:
        raise VideoError(located('expected a JSON object of key frames, {"0": {"point": [x, y], ...}, ...}, '
                                 "with at least one frame", where))
    allowed = None if names is None else set(names)
    out: Keyframes = {}
    for key, points in data.items():
        frame = _frame_index(key, where)
        if frame in out:
            raise VideoError(located(f"key frame {frame} is given twice", where))
        if frame_count is not None and frame >= frame_count:
            raise VideoError(located(f"key frame {frame} is past the video's end (it has {frame_count} frames, "
                                     "numbered from 0)", where))
        if not isinstance(points, Mapping) or not points:
            raise VideoError(located(f"key frame {frame}: expected an object of points, "
                                     '{"name": [x, y], ...}, with at least one point', where))
        for name in points:
            if allowed is not None and name not in allowed:
                raise VideoError(located(f"key frame {frame}: {name!r} is not a point of the chain (its points: "
                                         f"{', '.join(names or ())})", where))
        out[frame] = {str(n): _point(v, frame, str(n), where, image_size) for n, v in points.items()}
    if all(p is None for pts in out.values() for p in pts.values()):
        raise VideoError(located("the key frames place no point (every position is null)", where))
    return dict(sorted(out.items()))


def point_names(keyframes: Keyframes, names: Sequence[str] | None = None) -> list[str]:
    """The points to track: ``names`` (a chain's joints) if given, else in order of first appearance."""
    if names is not None:
        return list(names)
    seen: dict[str, None] = {}
    for points in keyframes.values():
        seen.update(dict.fromkeys(points))
    return list(seen)


def save_keyframes(path: str | os.PathLike, keyframes: Mapping[Any, Any], overwrite: bool = False) -> Path:
    """Write key frames (checked by :func:`load_keyframes`) as JSON, atomically."""
    from ..io.results import atomic_write

    checked = load_keyframes(keyframes)
    doc = {str(f): {n: (None if p is None else [p[0], p[1]]) for n, p in pts.items()} for f, pts in checked.items()}
    with atomic_write(path, "w", overwrite) as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    return Path(path)
