"""A calibrated pinhole camera with OpenCV's lens distortion, for real footage.

:class:`PinholeCamera` holds the intrinsics: focal lengths ``fx, fy`` and principal point ``cx, cy`` in
pixels, OpenCV's five distortion coefficients ``(k1, k2, p1, p2, k3)`` (the "plumb bob" model) and,
when known, the image size. A point ``(X, Y, Z)`` in the camera frame (x right, y down, z forward,
metres) lands at

    x, y = X / Z, Y / Z,  r2 = x^2 + y^2
    x' = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)
    y' = y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y
    u, v = fx x' + cx,  fy y' + cy

exactly as ``cv2.projectPoints``. Pixel coordinates follow OpenCV too: pixel centres at integers, so
an image of width W spans ``[-0.5, W - 0.5]`` and its centre is ``(W - 1) / 2``.

A camera comes from a matrix (:meth:`PinholeCamera.from_matrix`), a field of view
(:meth:`~PinholeCamera.from_fov`), a lens and sensor (:meth:`~PinholeCamera.from_focal_mm`) or a
calibration file (:meth:`~PinholeCamera.load`: OpenCV YAML/XML as ``cv2.FileStorage`` writes it after
``calibrateCamera``, JSON, ROS ``camera_info`` YAML). :func:`as_camera` turns whatever a caller
passes as ``intrinsics`` into a camera.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CameraError, DescriptionNotFoundError, is_real, located
from ..io.results import atomic_write, check_writable, write_json

__all__ = ["PinholeCamera", "as_camera", "CameraError"]

# The distortion models whose coefficients are the first five of OpenCV's vector.
_PLUMB_BOB = {"plumb_bob", "radtan", "radial-tangential", "opencv", "rational_polynomial"}

# Names calibration tools use for each quantity, tried in this order (case-sensitive first, then not).
_K_KEYS = ("camera_matrix", "K", "k", "cameraMatrix", "camera_matrix_k", "intrinsic_matrix",
           "intrinsics", "mtx", "M")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "dist", "D", "d", "distCoeffs", "distortion",
           "dist_coefs", "distortion_coeffs")
_W_KEYS = ("image_width", "width", "imageWidth", "img_width")
_H_KEYS = ("image_height", "height", "imageHeight", "img_height")
_SIZE_KEYS = ("image_size", "imageSize", "resolution")


def _matrix(values: Any, what: str, source: object = None) -> np.ndarray:
    """A finite (3, 3) float intrinsic matrix from a 3x3 or flat-9 array-like."""
    try:
        K = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise CameraError(located(f"{what} is not a numeric matrix", source)) from None
    if K.size == 9:
        K = K.reshape(3, 3)
    if K.shape != (3, 3):
        raise CameraError(located(f"{what} has shape {K.shape}: expected (3, 3) (or 9 numbers)", source))
    if not np.all(np.isfinite(K)):
        raise CameraError(located(f"{what} has non-finite entries", source))
    return K


def _size(width: Any, height: Any, source: object = None) -> tuple[int | None, int | None]:
    if width is None and height is None:
        return None, None
    out = []
    for name, v in (("width", width), ("height", height)):
        if v is None:
            raise CameraError(located(f"image {name} is missing: give both width and height or neither", source))
        if isinstance(v, np.ndarray) and v.size == 1:
            v = v.item()
        if not is_real(v) or float(v) != int(v) or v <= 0:
            raise CameraError(located(f"image {name} must be a positive whole number of pixels, not {v!r}", source))
        out.append(int(v))
    return out[0], out[1]


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """Pinhole intrinsics with OpenCV's 5-coefficient distortion.

    Parameters
    ----------
    fx, fy : float
        Focal lengths, pixels (> 0).
    cx, cy : float
        Principal point, pixels (pixel centres at integers, as in OpenCV).
    dist : array-like, optional
        Distortion ``(k1, k2, p1, p2, k3)``, dimensionless; 4 coefficients mean ``k3 = 0``; None or
        empty means none (the default).
    width, height : int, optional
        Image size, pixels; both or neither.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int | None = None
    height: int | None = None

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if isinstance(v, np.ndarray) and v.size == 1:
                v = v.item()
            if not is_real(v):
                raise CameraError(f"camera {name} must be a finite number of pixels, not {v!r}")
            object.__setattr__(self, name, float(v))
        if self.fx <= 0 or self.fy <= 0:
            raise CameraError(f"camera focal lengths must be positive pixels, not fx={self.fx:g}, fy={self.fy:g}")
        object.__setattr__(self, "dist", _dist(self.dist))
        w, h = _size(self.width, self.height)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)

    # ------------------------------------------------------------------------------- value object
    def _key(self) -> tuple:
        return (self.fx, self.fy, self.cx, self.cy, tuple(self.dist.tolist()), self.width, self.height)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PinholeCamera) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        size = "" if self.width is None else f", width={self.width}, height={self.height}"
        dist = "" if not self.has_distortion else f", dist={np.array2string(self.dist, precision=6)}"
        return f"PinholeCamera(fx={self.fx:g}, fy={self.fy:g}, cx={self.cx:g}, cy={self.cy:g}{dist}{size})"

    # ------------------------------------------------------------------------------- properties
    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix, pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def image_size(self) -> tuple[int, int] | None:
        """``(width, height)`` in pixels, or None when unknown."""
        return None if self.width is None else (self.width, self.height)

    @property
    def has_distortion(self) -> bool:
        """Whether any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0.0))

    @property
    def fov_deg(self) -> tuple[float, float] | None:
        """``(horizontal, vertical)`` field of view in degrees, edge to edge, or None when the size is
        unknown. Distortion is ignored (it is the field of view of the undistorted image)."""
        if self.width is None:
            return None
        h = math.atan((self.cx + 0.5) / self.fx) + math.atan((self.width - 0.5 - self.cx) / self.fx)
        v = math.atan((self.cy + 0.5) / self.fy) + math.atan((self.height - 0.5 - self.cy) / self.fy)
        return math.degrees(h), math.degrees(v)

    def corners(self) -> np.ndarray:
        """(4, 2) outer corners of the image in pixels (top-left, top-right, bottom-right, bottom-left)."""
        if self.width is None:
            raise CameraError("the camera's image size is unknown: give width and height")
        x0, y0, x1, y1 = -0.5, -0.5, self.width - 0.5, self.height - 0.5
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])

    # ------------------------------------------------------------------------------- constructors
    @classmethod
    def from_matrix(cls, K: Any, dist: Any = None, width: int | None = None,
                    height: int | None = None) -> PinholeCamera:
        """Camera from a (3, 3) intrinsic matrix ``K`` (pixels) and optional distortion and size.

        ``K`` must be upper triangular with zero skew and last row ``(0, 0, 1)`` (any positive
        multiple of it is normalised).
        """
        return cls._from_matrix(K, dist, width, height, None)

    @classmethod
    def _from_matrix(cls, K: Any, dist: Any, width: Any, height: Any, source: object) -> PinholeCamera:
        K = _matrix(K, "the camera matrix", source)
        if K[2, 2] <= 0 or abs(K[2, 0]) > 1e-12 * K[2, 2] or abs(K[2, 1]) > 1e-12 * K[2, 2]:
            raise CameraError(located(f"the camera matrix's last row must be (0, 0, 1), not {K[2].tolist()}", source))
        K = K / K[2, 2]
        if abs(K[1, 0]) > 1e-9 * abs(K[1, 1]) or abs(K[0, 1]) > 1e-9 * abs(K[0, 0]):
            raise CameraError(located("the camera matrix has skew or is not upper triangular; "
                                     "only zero-skew pinhole cameras are supported", source))
        w, h = _size(width, height, source)
        try:
            return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.zeros(5) if dist is None else dist, w, h)
        except CameraError as exc:
            raise CameraError(located(str(exc), source)) from None

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float, axis: str = "horizontal") -> PinholeCamera:
        """Camera with square pixels, no distortion and the principal point at the image centre.

        ``fov_deg`` (degrees, in (0, 180)) is the field of view across the ``axis``: "horizontal"
        (the width), "vertical" (the height) or "diagonal".
        """
        w, h = _size(width, height)
        if not is_real(fov_deg) or not 0.0 < fov_deg < 180.0:
            raise CameraError(f"the field of view must be between 0 and 180 degrees, not {fov_deg!r}")
        spans = {"horizontal": w, "vertical": h, "diagonal": math.hypot(w, h)}
        if axis not in spans:
            raise CameraError(f"axis must be 'horizontal', 'vertical' or 'diagonal', not {axis!r}")
        f = 0.5 * spans[axis] / math.tan(math.radians(fov_deg) / 2.0)
        return cls(f, f, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(5), w, h)

    @classmethod
    def from_focal_mm(cls, focal_mm: float, sensor_width_mm: float, width: int, height: int) -> PinholeCamera:
        """Camera from a lens's focal length and the sensor width, both millimetres.

        The image (``width`` x ``height`` pixels) is taken to cover the sensor's full width with
        square pixels; the principal point is at the image centre and there is no distortion.
        """
        w, h = _size(width, height)
        for name, v in (("focal_mm", focal_mm), ("sensor_width_mm", sensor_width_mm)):
            if not is_real(v) or v <= 0:
                raise CameraError(f"{name} must be a positive number of millimetres, not {v!r}")
        f = float(focal_mm) * w / float(sensor_width_mm)
        return cls(f, f, (w - 1) / 2.0, (h - 1) / 2.0, np.zeros(5), w, h)

    @classmethod
    def load(cls, path: str | os.PathLike) -> PinholeCamera:
        """Read a calibration file.

        Formats, by content and suffix:

        * OpenCV YAML (``.yaml``/``.yml``, ``%YAML`` header, ``!!opencv-matrix``) or XML (``.xml``) as
          ``cv2.FileStorage`` writes them, keys ``camera_matrix`` and ``distortion_coefficients``
          (or ``K``/``D``/``dist_coeffs``...), ``image_width`` and ``image_height``;
        * JSON: ``{"K": [[...]], "dist": [...], "width": W, "height": H}`` or ``fx, fy, cx, cy``;
        * ROS ``camera_info`` YAML (``camera_matrix: {rows, cols, data}``, ``distortion_coefficients``,
          ``distortion_model: plumb_bob``) and the message form (``K``/``D`` or ``k``/``d`` lists,
          ``width``/``height``).
        """
        path = Path(path)
        if not path.is_file():
            raise DescriptionNotFoundError(f"{path}: no such calibration file")
        suffix = path.suffix.lower()
        try:
            head = path.read_bytes()[:4096]
        except OSError as exc:
            raise CameraError(f"{path}: cannot read: {exc.strerror or exc}") from None
        text_head = head.decode("utf-8", errors="replace").lstrip("\ufeff").lstrip()
        if suffix == ".json" or (suffix not in (".yaml", ".yml", ".xml") and text_head.startswith("{")):
            data = _read_json(path)
        elif suffix == ".xml" or text_head.startswith("<?xml") or text_head.startswith("%YAML") \
                or "!!opencv-matrix" in text_head:
            data = _read_filestorage(path)
        elif suffix in (".yaml", ".yml"):
            data = _read_yaml(path)
        else:
            raise CameraError(f"{path}: unknown calibration format {suffix or '(no suffix)'!r}: "
                              "expected .yaml, .yml, .xml or .json")
        return _from_mapping(data, path)

    # ------------------------------------------------------------------------------- writing
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``{"K", "dist", "width", "height", "fx", "fy", "cx", "cy"}`` (pixels)."""
        return {"K": self.K.tolist(), "dist": self.dist.tolist(), "width": self.width, "height": self.height,
                "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "distortion_model": "plumb_bob"}

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the camera as OpenCV YAML (``.yaml``/``.yml``), OpenCV XML (``.xml``) or JSON (``.json``).

        The OpenCV files use ``calibrateCamera``'s usual keys (``image_width``, ``image_height``,
        ``camera_matrix``, ``distortion_coefficients``) and read back with ``cv2.FileStorage``. The
        write is atomic and refuses to replace an existing file unless ``overwrite``.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".json":
            return write_json(path, self.to_dict(), overwrite=overwrite)
        if suffix not in (".yaml", ".yml", ".xml"):
            raise CameraError(f"{path}: cannot save a camera as {suffix or '(no suffix)'!r}: "
                              "use .yaml, .yml, .xml or .json")
        check_writable([path], overwrite)
        cv2 = _cv2()
        # FileStorage's in-memory mode takes the format from the name's suffix
        fs = cv2.FileStorage(f"camera{suffix}", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
        if self.width is not None:
            fs.write("image_width", int(self.width))
            fs.write("image_height", int(self.height))
        fs.write("camera_matrix", self.K)
        fs.write("distortion_coefficients", self.dist.reshape(1, 5))
        text = fs.releaseAndGetString()
        with atomic_write(path, "w", overwrite) as f:
            f.write(text)
        return path

    # ------------------------------------------------------------------------------- geometry
    def distort(self, normalised: Any) -> np.ndarray:
        """Normalised image coordinates (..., 2) (x/z, y/z) -> pixels (..., 2), with distortion."""
        xy = np.asarray(normalised, dtype=float)
        d, _ = _distortion(xy, self.dist, jacobian=False)
        return d * np.array([self.fx, self.fy]) + np.array([self.cx, self.cy])

    def project(self, points_cam: Any) -> np.ndarray:
        """Pixels (..., 2) of points (..., 3) in the camera frame (x right, y down, z forward, metres).

        Distortion is applied, as ``cv2.projectPoints`` does. Points at or behind the camera (z <= 0)
        or with NaN give NaN. Like OpenCV's, the distortion polynomial is only meaningful over the
        calibrated field of view: far outside it, a strongly distorting lens model can fold points back.
        """
        return self._project(points_cam, jacobian=False)[0]

    def project_with_jacobian(self, points_cam: Any) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) and their derivative with respect to the point, (..., 2, 3) pixels per metre.

        Analytic and vectorised; NaN (both) where :meth:`project` gives NaN.
        """
        return self._project(points_cam, jacobian=True)

    def _project(self, points_cam: Any, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        P = _points(points_cam, 3, "points_cam")
        z = P[..., 2]
        ok = np.isfinite(P).all(axis=-1) & (z > 0)
        zs = np.where(ok, z, 1.0)
        xy = np.where(ok[..., None], P[..., :2], 0.0) / zs[..., None]
        d, Jd = _distortion(xy, self.dist, jacobian)
        f = np.array([self.fx, self.fy])
        uv = d * f + np.array([self.cx, self.cy])
        uv[~ok] = np.nan
        if not jacobian:
            return uv, None
        # d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]
        Jn = np.zeros(P.shape[:-1] + (2, 3))
        Jn[..., 0, 0] = Jn[..., 1, 1] = 1.0 / zs
        Jn[..., :, 2] = -xy / zs[..., None]
        J = f[:, None] * (Jd @ Jn)
        J[~ok] = np.nan
        return uv, J

    def undistort(self, pixels: Any) -> np.ndarray:
        """Pixels (..., 2) of the distorted image -> where the same rays land without distortion, in the
        same ``K`` (pixels). NaN rows stay NaN."""
        uv = _points(pixels, 2, "pixels")
        if not self.has_distortion:
            return uv.copy()
        xy = self._undistort_normalised(uv)
        return xy * np.array([self.fx, self.fy]) + np.array([self.cx, self.cy])

    def rays(self, pixels: Any) -> np.ndarray:
        """Normalised image coordinates (..., 2), ``(x/z, y/z)`` of each pixel's ray, distortion removed."""
        uv = _points(pixels, 2, "pixels")
        if not self.has_distortion:
            return (uv - np.array([self.cx, self.cy])) / np.array([self.fx, self.fy])
        return self._undistort_normalised(uv)

    def _undistort_normalised(self, uv: np.ndarray) -> np.ndarray:
        flat = uv.reshape(-1, 2)
        ok = np.isfinite(flat).all(axis=1)
        out = np.full(flat.shape, np.nan)
        if ok.any():
            cv2 = _cv2()
            src = np.ascontiguousarray(flat[ok], dtype=np.float64).reshape(-1, 1, 2)
            # OpenCV's fixed-point iteration (its default 5 steps) is the start; Newton on the model
            # then reaches machine precision in a step or two, where more fixed-point steps are slow
            # to converge under strong distortion and an EPS criterion costs a reprojection per step
            start = cv2.undistortPoints(src, self.K, self.dist).reshape(-1, 2)
            out[ok] = self._newton(start, (flat[ok] - [self.cx, self.cy]) / [self.fx, self.fy])
        return out.reshape(uv.shape)

    def _newton(self, xy: np.ndarray, target: np.ndarray, steps: int = 8) -> np.ndarray:
        """Solve distort(xy) = target (normalised, (N, 2)) by Newton steps from ``xy``; a point whose
        residual stops falling (past a fold of the model, or converged) keeps its best value."""
        xy = xy.copy()
        active = np.arange(len(xy))
        r = _distortion(xy, self.dist, False)[0] - target
        err = np.abs(r).max(axis=1)
        for _ in range(steps):
            active = active[err[active] > 1e-15]
            if not len(active):
                break
            _, J = _distortion(xy[active], self.dist, True)
            ra = r[active]
            a, b, c, e = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
            with np.errstate(divide="ignore", invalid="ignore"):  # a singular J is rejected below
                det = (a * e - b * c)[:, None]
                step = np.column_stack([e * ra[:, 0] - b * ra[:, 1], a * ra[:, 1] - c * ra[:, 0]]) / det
            trial = xy[active] - step
            rt = _distortion(trial, self.dist, False)[0] - target[active]
            et = np.abs(rt).max(axis=1)
            better = np.isfinite(et) & (et < err[active])
            idx = active[better]
            xy[idx], r[idx], err[idx] = trial[better], rt[better], et[better]
            active = idx
        return xy

    def scaled(self, factor: float) -> PinholeCamera:
        """The camera of the images resized by ``factor`` (e.g. 0.5 for half size), as ``cv2.resize``
        maps pixels: ``u' = (u + 0.5) * factor - 0.5``. Distortion is unchanged (it acts on normalised
        coordinates). The image size is rounded to whole pixels."""
        if not is_real(factor) or factor <= 0:
            raise CameraError(f"the scale factor must be a positive number, not {factor!r}")
        s = float(factor)
        w = None if self.width is None else max(1, round(self.width * s))
        h = None if self.height is None else max(1, round(self.height * s))
        return PinholeCamera(self.fx * s, self.fy * s, (self.cx + 0.5) * s - 0.5, (self.cy + 0.5) * s - 0.5,
                             self.dist, w, h)

    def with_size(self, width: int, height: int) -> PinholeCamera:
        """The same intrinsics with the image size set."""
        return PinholeCamera(self.fx, self.fy, self.cx, self.cy, self.dist, width, height)


# ----------------------------------------------------------------------------------- the model
def _distortion(xy: np.ndarray, dist: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Distorted normalised coordinates (..., 2) and, if asked, d distorted / d undistorted (..., 2, 2)."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    out = np.stack([xd, yd], axis=-1)
    if not jacobian:
        return out, None
    dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # d radial / d r2, times 2 for d r2 / d x = 2x
    J = np.empty(xy.shape[:-1] + (2, 2))
    J[..., 0, 0] = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    J[..., 0, 1] = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J[..., 1, 0] = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J[..., 1, 1] = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return out, J


def _dist(values: Any, source: object = None) -> np.ndarray:
    """Read-only (5,) distortion ``(k1, k2, p1, p2, k3)``; 4 coefficients pad k3 = 0, and longer vectors
    (OpenCV's 8, 12, 14) are accepted only when everything past k3 is zero."""
    if values is None:
        values = ()
    try:
        d = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise CameraError(located(f"distortion coefficients are not numbers: {values!r}", source)) from None
    if d.size in (0, 4):
        d = np.concatenate([d, np.zeros(5 - d.size)])
    elif d.size > 5 and not np.any(d[5:]):
        d = d[:5]
    if d.size != 5:
        raise CameraError(located(
            f"{d.size} distortion coefficients: expected 4 or 5 (k1, k2, p1, p2[, k3]); the rational and "
            "thin-prism terms of OpenCV's longer vectors are not supported", source))
    if not np.all(np.isfinite(d)):
        raise CameraError(located("distortion coefficients must be finite", source))
    d = d.copy()
    d.setflags(write=False)  # the camera is immutable; so is its distortion
    return d


def _points(values: Any, dim: int, what: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise CameraError(f"{what} must be numbers") from None
    if a.ndim == 0 or a.shape[-1] != dim:
        raise CameraError(f"{what} has shape {a.shape}: expected (..., {dim})")
    return a


def _cv2() -> Any:
    try:
        import cv2
    except ImportError as exc:  # pragma: no cover - a dependency
        raise CameraError(f"OpenCV is needed for this (pip install opencv-python-headless): {exc}") from None
    return cv2


# ----------------------------------------------------------------------------------- reading files
def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise CameraError(f"{path}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise CameraError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    if not isinstance(data, dict):
        raise CameraError(f"{path}: expected a JSON object with the camera's intrinsics")
    return data


def _read_yaml(path: Path) -> dict:
    import yaml

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise CameraError(f"{path}: cannot read: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise CameraError(f"{path}{line}: not valid YAML: {getattr(exc, 'problem', None) or exc}") from None
    if not isinstance(data, dict):
        raise CameraError(f"{path}: expected a YAML mapping with the camera's intrinsics")
    return data


def _read_filestorage(path: Path) -> dict:
    cv2 = _cv2()
    # FileStorage prints its own parse errors and raises cv2.error; turn both into one clear message
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # SystemError wraps the cv2.error of a parse error
        raise CameraError(_filestorage_message(path, exc.__cause__ or exc)) from None
    try:
        if not fs.isOpened():
            raise CameraError(f"{path}: OpenCV cannot open it as a calibration file")
        root = fs.root()
        return {key: _node_value(root.getNode(key)) for key in root.keys()}
    except cv2.error as exc:  # a matrix node OpenCV cannot decode
        raise CameraError(_filestorage_message(path, exc)) from None
    finally:
        fs.release()


def _filestorage_message(path: Path, exc: BaseException) -> str:
    """OpenCV's parse error as ``file:line: problem``; its own text names the file and line in a
    C++ function's signature."""
    text = str(exc).strip()
    found = re.search(r"\((\d+)\):\s*(.+?)'?\s*$", text)
    if found:
        return f"{path}:{found.group(1)}: not a readable OpenCV calibration file: {found.group(2)}"
    return f"{path}: not a readable OpenCV calibration file: {text.splitlines()[-1] if text else 'parse error'}"


def _node_value(node: Any) -> Any:
    """A FileStorage node as Python: matrices as arrays, numbers, strings, lists, dicts."""
    if node.isMap():
        keys = node.keys()
        if {"rows", "cols", "data"} <= set(keys) and "dt" in keys:
            return node.mat()
        return {k: _node_value(node.getNode(k)) for k in keys}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


def _lookup(data: Mapping, keys: tuple[str, ...]) -> tuple[str | None, Any]:
    for key in keys:
        if key in data and data[key] is not None:
            return key, data[key]
    lower = {str(k).lower(): k for k in data}
    for key in keys:
        if key.lower() in lower and data[lower[key.lower()]] is not None:
            return lower[key.lower()], data[lower[key.lower()]]
    return None, None


def _unwrap(value: Any, key: str, source: object) -> Any:
    """ROS's ``{rows, cols, data}`` (and FileStorage-like maps) as an array shaped rows x cols."""
    if isinstance(value, Mapping):
        if "data" not in value:
            raise CameraError(located(f"{key!r} has no 'data'", source))
        try:
            data = np.asarray(value["data"], dtype=float)
            if "rows" in value and "cols" in value:
                data = data.reshape(int(value["rows"]), int(value["cols"]))
        except (TypeError, ValueError):
            raise CameraError(located(f"{key!r}: data does not fit rows x cols or is not numeric", source)) from None
        return data
    return value


def _from_mapping(data: Mapping, source: object) -> PinholeCamera:
    model = data.get("distortion_model")
    if isinstance(model, str) and model.strip().lower() not in _PLUMB_BOB:
        raise CameraError(located(f"distortion_model {model!r} is not supported: only plumb_bob "
                                 "(OpenCV's k1, k2, p1, p2, k3)", source))
    size_key, size = _lookup(data, _SIZE_KEYS)
    wk, width = _lookup(data, _W_KEYS)
    hk, height = _lookup(data, _H_KEYS)
    if width is None and height is None and size is not None:
        try:
            size = np.asarray(_unwrap(size, size_key, source), dtype=float).ravel()
        except (TypeError, ValueError):
            size = np.zeros(0)
        if size.size != 2:
            raise CameraError(located(f"{size_key!r} must be [width, height] in pixels", source))
        width, height = size.tolist()
    # ROS's message form stores 0 x 0 when the size is not known
    if is_real(width) and is_real(height) and width == 0 and height == 0:
        width = height = None
    dkey, dist = _lookup(data, _D_KEYS)
    dist = None if dist is None else _dist(_unwrap(dist, dkey, source), f"{source} ({dkey})" if source else dkey)
    kkey, K = _lookup(data, _K_KEYS)
    if K is not None:
        K = _matrix(_unwrap(K, kkey, source), f"{kkey!r}", source)
        return PinholeCamera._from_matrix(K, dist, width, height, source)
    parts = {}
    for name in ("fx", "fy", "cx", "cy"):
        _, parts[name] = _lookup(data, (name,))
    if parts["fx"] is not None and parts["fy"] is None:
        parts["fy"] = parts["fx"]  # one focal length means square pixels
    missing = [n for n, v in parts.items() if v is None]
    if missing:
        raise CameraError(located(
            f"no camera matrix: expected a key {' / '.join(repr(k) for k in _K_KEYS[:4])} or the numbers "
            f"fx, fy, cx, cy (missing {', '.join(missing)})", source))
    try:
        return PinholeCamera(parts["fx"], parts["fy"], parts["cx"], parts["cy"],
                             np.zeros(5) if dist is None else dist, *_size(width, height, source))
    except CameraError as exc:
        raise CameraError(located(str(exc), source)) from None


# ----------------------------------------------------------------------------------- as_camera
def as_camera(intrinsics: Any, image_size: tuple[int, int] | None = None) -> PinholeCamera | None:
    """Whatever a caller passes as ``intrinsics`` as a :class:`PinholeCamera`, or None for None.

    Parameters
    ----------
    intrinsics : None, PinholeCamera, array-like (3, 3) or str / Path
        A camera, an intrinsic matrix (pixels) or a calibration file (see :meth:`PinholeCamera.load`).
    image_size : (int, int), optional
        ``(width, height)`` of the images, pixels. Fills in a camera's unknown size; a camera
        calibrated at another size is an error (resize it with :meth:`PinholeCamera.scaled`).
    """
    if intrinsics is None:
        return None
    if isinstance(intrinsics, PinholeCamera):
        camera = intrinsics
    elif isinstance(intrinsics, (str, os.PathLike)):
        camera = PinholeCamera.load(intrinsics)
    elif isinstance(intrinsics, (np.ndarray, list, tuple)):
        camera = PinholeCamera.from_matrix(intrinsics)
    else:
        raise CameraError(f"intrinsics must be a PinholeCamera, a 3x3 matrix or a calibration file path, "
                          f"not a {type(intrinsics).__name__}")
    if image_size is None:
        return camera
    try:
        w, h = (int(v) if is_real(v) and float(v) == int(v) else v for v in image_size)
    except (TypeError, ValueError):
        raise CameraError(f"image_size must be (width, height), not {image_size!r}") from None
    w, h = _size(w, h)
    if camera.image_size is None:
        return camera.with_size(w, h)
    if camera.image_size != (w, h):
        raise CameraError(f"the camera was calibrated for {camera.width}x{camera.height} images but these are "
                          f"{w}x{h}; scale it with camera.scaled(...) if the images were resized")
    return camera
