"""Camera models shared by every stage.

* :mod:`.weak` - the paper's per-frame weak-perspective camera (a scaled orthographic projection).
  Right when the subject is far from the camera compared with its own depth (telephoto, far views),
  and the start of every solver, since it needs no intrinsics and has a closed form.
* :mod:`.pinhole` - :class:`PinholeCamera`, a calibrated perspective camera with OpenCV's lens
  distortion, read from a calibration file, a matrix or a field of view. Right for real footage,
  where the subject is close enough for perspective to matter.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["PinholeCamera", "as_camera", "fit_cameras", "project"]

# Loaded on first use, like the package's own exports: the weak camera must not pull in OpenCV.
_EXPORTS = {"PinholeCamera": ".pinhole", "as_camera": ".pinhole", "fit_cameras": ".weak", "project": ".weak"}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'chainspace.cameras' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


if TYPE_CHECKING:  # pragma: no cover
    from .pinhole import PinholeCamera, as_camera
    from .weak import fit_cameras, project
