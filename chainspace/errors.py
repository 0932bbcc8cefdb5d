"""The exceptions and warnings chainspace raises.

Every error chainspace raises on purpose derives from :class:`ChainspaceError`, so a caller can catch
one class. The subclasses also derive from the matching built-in (``ValueError``,
``FileNotFoundError``, ``FileExistsError``) so that code written against the built-ins keeps working.
Messages name what is wrong and where: the file, the line, the joint, the frame.

:func:`located` and :func:`is_real` help write them: where a problem is, and whether an option is a
finite number.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ChainspaceError",
    "DescriptionError",
    "DescriptionNotFoundError",
    "TrackError",
    "CameraError",
    "VideoError",
    "OutputExistsError",
    "ConvergenceWarning",
    "located",
    "is_real",
]


class ChainspaceError(Exception):
    """Base class of every error chainspace raises on purpose."""


class DescriptionError(ChainspaceError, ValueError):
    """A chain description (URDF, ASF, AMC, BVH, skeleton file, or arguments) is malformed."""


class DescriptionNotFoundError(ChainspaceError, FileNotFoundError):
    """A description or data file does not exist."""


class TrackError(ChainspaceError, ValueError):
    """2D tracks, poses or confidences that cannot be used as given."""


class CameraError(ChainspaceError, ValueError):
    """Camera intrinsics (values, a matrix or a calibration file) that cannot be used as given."""


class VideoError(ChainspaceError, ValueError):
    """A video or image folder (or its key frames) that cannot be read or used as given."""


class OutputExistsError(ChainspaceError, FileExistsError):
    """Writing would overwrite an existing file and overwriting was not asked for."""


class ConvergenceWarning(UserWarning):
    """A solver stopped before it converged; the result is still returned, flagged."""


def is_real(x: object) -> bool:
    """Whether an option's value x is a finite real number (not a bool, a string or an array)."""
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and bool(np.isfinite(x))


def located(message: str, source: object = None, line: int | None = None) -> str:
    """Prefix ``message`` with ``source`` (a file name) and ``line`` (1-based) when they are known."""
    if source is None:
        return message
    where = f"{source}:{line}" if line is not None else f"{source}"
    return f"{where}: {message}"
