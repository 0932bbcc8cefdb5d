"""ArUco markers stuck on a robot's links: the marker map, detection in video, and the chain they track.

A *marker map* says where each printed marker sits on the robot: one row per marker with its id in the
dictionary (``DICT_4X4_50`` unless the file says otherwise), the URDF link it is stuck on, the offset of
its centre in that link's frame (x, y, z, metres), its orientation (roll, pitch, yaw, radians, URDF
convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``; blank = 0) and its side (metres, black border included).
The marker's z axis is its outward normal, its y axis points to the top of the printed marker. CSV::

    # comment lines start with '#'
    id,link,x,y,z,roll,pitch,yaw,size
    0,base_link,0.405,0,0.22,0,1.5707963,0,0.22

:func:`detect_markers` finds the markers in every frame of a video with OpenCV's ``cv2.aruco``
(``ArucoDetector``, sub-pixel corner refinement) and returns their corners (F, M, 4, 2) and centres
(F, M, 2), NaN where a marker is not seen. The centres are tracked points of the chain
:func:`marker_chain` makes from the URDF (each marker an ``extra_frame`` of its link), so the tracks go
straight into :func:`chainspace.reconstruct` and :func:`chainspace.fit_joint_angles`.

Pixels: x right, y down, pixel centres at integers (OpenCV). Corner order: OpenCV's (top-left,
top-right, bottom-right, bottom-left of the printed marker).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ChainspaceError, DescriptionError, DescriptionNotFoundError
from ..progress import progress_reporter
from .reader import open_video

__all__ = ["Marker", "MarkerMap", "MarkerError", "load_marker_map", "detect_markers", "marker_chain",
           "MarkerTracks", "marker_corners_local", "save_marker_tracks", "shipped_marker_map"]

COLUMNS = ("id", "link", "x", "y", "z", "roll", "pitch", "yaw", "size")
OPTIONAL = ("roll", "pitch", "yaw")


class MarkerError(DescriptionError):
    """A marker map that cannot be used (names the file, line and field)."""


@dataclass(frozen=True)
class Marker:
    """One marker: ``id`` in the dictionary, ``link`` it is stuck on, ``xyz`` its centre in the link's
    frame (metres), ``rpy`` its orientation (radians), ``size`` its side (metres)."""

    id: int
    link: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    size: float

    @property
    def name(self) -> str:
        """Its point name in the chain (``marker_<id>``)."""
        return f"marker_{self.id}"

    def rotation(self) -> np.ndarray:
        """(3, 3) rotation of the marker frame in its link's frame."""
        r, p, y = self.rpy
        cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
        Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        return Rz @ Ry @ Rx

    def corners_in_link(self) -> np.ndarray:
        """(4, 3) corners in the link's frame, metres, in OpenCV's order."""
        return marker_corners_local(self.size) @ self.rotation().T + np.asarray(self.xyz)


def marker_corners_local(size: float) -> np.ndarray:
    """(4, 3) corners of a marker of side ``size`` (metres) in its own frame (z out of the marker, y to
    its top): top-left, top-right, bottom-right, bottom-left, as ``cv2.aruco`` orders them."""
    h = size / 2
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass
class MarkerMap:
    """The markers of a robot (see the module docstring); ``dictionary`` names the ``cv2.aruco``
    dictionary, ``source`` the file."""

    markers: list[Marker]
    dictionary: str = "DICT_4X4_50"
    source: str = ""

    def __len__(self) -> int:
        return len(self.markers)

    @property
    def ids(self) -> list[int]:
        return [m.id for m in self.markers]

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.markers]

    def extra_frames(self) -> dict[str, tuple[str, list[float]]]:
        """``{marker_<id>: (link, [x, y, z])}``: the markers' centres as ``from_urdf`` extra frames."""
        return {m.name: (m.link, list(m.xyz)) for m in self.markers}

    def aruco_dictionary(self) -> Any:
        import cv2

        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))


def load_marker_map(path: str | os.PathLike, *, urdf: str | os.PathLike | None = None) -> MarkerMap:
    """Read a marker map CSV (see the module docstring). A ``# dictionary: DICT_5X5_100`` comment line
    picks another ``cv2.aruco`` dictionary. With ``urdf``, every link must be one of its links.

    Raises :class:`MarkerError` naming the file, line and field for a missing column, a value that is
    not a number, a duplicate id, an id outside the dictionary, a size <= 0 or an unknown link.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise DescriptionNotFoundError(f"marker map not found: {path}")
    dictionary = "DICT_4X4_50"
    markers: list[Marker] = []
    header: list[str] | None = None
    lines: dict[int, int] = {}
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MarkerError(f"{path}: cannot read the marker map ({exc})") from None
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip():
            continue
        first = row[0].strip()
        if first.startswith("#"):
            key, _, value = ",".join(row).lstrip("#").partition(":")
            if key.strip().lower() == "dictionary":
                dictionary = value.strip()
                if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
                    raise MarkerError(f"{path}:{lineno}: unknown aruco dictionary {dictionary!r} "
                                      "(e.g. DICT_4X4_50, DICT_5X5_100, DICT_APRILTAG_36h11)")
            continue
        cells = [c.strip() for c in row]
        if header is None:
            header = [c.lower() for c in cells]
            missing = [c for c in COLUMNS if c not in header and c not in OPTIONAL]
            if missing:
                raise MarkerError(f"{path}:{lineno}: the header lacks column(s) {', '.join(missing)}; "
                                  f"expected {','.join(COLUMNS)}")
            continue
        if len(cells) > len(header):
            raise MarkerError(f"{path}:{lineno}: {len(cells)} fields, the header has {len(header)}")
        rec = dict(zip(header, cells + [""] * (len(header) - len(cells))))

        def number(name: str, default: float | None = None) -> float:
            raw = rec.get(name, "")
            if raw == "" and default is not None:
                return default
            try:
                v = float(raw)
            except ValueError:
                raise MarkerError(f"{path}:{lineno}: field {name!r} is {raw!r}, not a number") from None
            if not np.isfinite(v):
                raise MarkerError(f"{path}:{lineno}: field {name!r} is not finite")
            return v

        raw_id = rec["id"]
        if not raw_id.isdigit():
            raise MarkerError(f"{path}:{lineno}: field 'id' is {raw_id!r}, not a marker id (an integer >= 0)")
        mid = int(raw_id)
        if mid in lines:
            raise MarkerError(f"{path}:{lineno}: marker id {mid} is already on line {lines[mid]}")
        if not rec["link"]:
            raise MarkerError(f"{path}:{lineno}: field 'link' is empty")
        size = number("size")
        if size <= 0:
            raise MarkerError(f"{path}:{lineno}: field 'size' is {size:g}; a marker's side is > 0 metres")
        xyz = (number("x"), number("y"), number("z"))
        rpy = (number("roll", 0.0), number("pitch", 0.0), number("yaw", 0.0))
        lines[mid] = lineno
        markers.append(Marker(mid, rec["link"], xyz, rpy, size))
    if not markers:
        raise MarkerError(f"{path}: no marker in the file (expected a header {','.join(COLUMNS)} and rows)")
    out = MarkerMap(markers, dictionary, str(path))
    n_ids = out.aruco_dictionary().bytesList.shape[0]
    for m in markers:
        if m.id >= n_ids:
            raise MarkerError(f"{path}:{lines[m.id]}: marker id {m.id} is not in {dictionary} "
                              f"(ids 0 to {n_ids - 1})")
    if urdf is not None:
        from ..io.urdf import _UrdfTree

        links = _UrdfTree(Path(urdf)).links
        for m in markers:
            if m.link not in links:
                raise MarkerError(f"{path}:{lines[m.id]}: field 'link' names {m.link!r}, which is not a link of "
                                  f"{Path(urdf).name} ({', '.join(links)})")
    return out


def shipped_marker_map(robot: str) -> Path:
    """Path of the marker map shipped for a robot of ``robots/`` (``"milling_arm"`` ->
    ``milling_arm.markers.csv``)."""
    import importlib.resources

    path = Path(str(importlib.resources.files("chainspace.robots") / f"{robot}.markers.csv"))
    if not path.is_file():
        raise DescriptionNotFoundError(f"no marker map is shipped for {robot!r} (robots/{robot}.markers.csv)")
    return path


# ---------------------------------------------------------------------------------------------------
# the chain the markers track
# ---------------------------------------------------------------------------------------------------
def marker_chain(urdf: str | os.PathLike, marker_map: MarkerMap, names: Sequence[str] | None = None):
    """The chain whose points are the markers' centres (``marker_<id>``), for ``reconstruct`` and
    ``fit_joint_angles``: each an extra frame of its link (``from_urdf(..., extra_frames=...)``). A
    marker hangs from the first marker of the nearest link at or above its own (the first marker of
    the shallowest link is the root), so the link origins, which no camera sees, are no points of it.
    ``names`` keeps only these markers (those seen in a video: a point never seen cannot be
    reconstructed)."""
    from ..chain import KinematicChain
    from ..io.urdf import from_urdf

    full = from_urdf(urdf, extra_frames=marker_map.extra_frames())
    keep = [m for m in marker_map.markers if names is None or m.name in set(names)]
    if len(keep) < 2:
        raise MarkerError(f"{marker_map.source}: {len(keep)} marker(s) to track; a chain needs at least 2")
    parent = {full.joints[i]: (full.joints[p] if p >= 0 else None) for i, p in enumerate(full.parents)}
    # link order from the root down, so every marker's parent marker comes first
    depth = {}
    for link in parent:
        d, k = 0, link
        while parent[k] is not None:
            d, k = d + 1, parent[k]
        depth[link] = d
    # a link welded to another by a fixed joint is one point of the chain with it (UR10: base_link in world)
    point_of = {link: kept for kept, links in full.metadata.get("merged", {}).items() for link in links}
    home = {m.name: point_of.get(m.link, m.link) for m in keep}
    keep.sort(key=lambda m: depth[home[m.name]])
    first: dict[str, str] = {}
    bones = []
    for m in keep:
        link = home[m.name]
        while link is not None and link not in first:
            link = parent[link]
        if link is not None:
            bones.append((first[link], m.name))
        elif first:  # a side branch with no marker above it: hang it from the root marker
            bones.append((keep[0].name, m.name))
        first.setdefault(home[m.name], m.name)
    pts = [m.name for m in keep]
    rest = full.rest_pose[[full.joint_index(n) for n in pts]]
    meta = dict(full.metadata)
    meta["extra_frames"] = {n: meta["extra_frames"][n] for n in pts}
    meta["variable_bones"] = [b for b in bones if _link(keep, b[0]) != _link(keep, b[1])]
    meta["merged"] = {}
    meta["marker_map"] = marker_map.source
    return KinematicChain(pts, bones, rest, name=f"{full.name} markers", source=full.source, metadata=meta)


def _link(markers: list[Marker], name: str) -> str:
    return next(m.link for m in markers if m.name == name)


# ---------------------------------------------------------------------------------------------------
# detection
# ---------------------------------------------------------------------------------------------------
@dataclass
class MarkerTracks:
    """Markers found in a video: ``corners`` (F, M, 4, 2) px and ``centres`` (F, M, 2) px (NaN where not
    seen), ``confidence`` (F, M) (1 seen, 0 not), ``names`` (``marker_<id>``, the map's order),
    ``fps``, ``image_size`` (w, h)."""

    corners: np.ndarray
    centres: np.ndarray
    confidence: np.ndarray
    names: list[str]
    fps: float
    image_size: tuple[int, int]
    marker_map: MarkerMap | None = field(default=None, repr=False)

    @property
    def seen(self) -> list[str]:
        """Names of the markers seen in at least one frame."""
        return [n for n, c in zip(self.names, self.confidence.max(0) if len(self.confidence) else []) if c > 0]


def centre_of(corners: np.ndarray) -> np.ndarray:
    """(..., 2) intersection of a quadrilateral's diagonals, from its corners (..., 4, 2): the image of a
    square's centre under a pinhole camera (the corners' mean is not, under perspective)."""
    p0, p1, p2, p3 = (corners[..., k, :] for k in range(4))
    d1, d2 = p2 - p0, p3 - p1
    cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    r = p1 - p0
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (r[..., 0] * d2[..., 1] - r[..., 1] * d2[..., 0]) / cross
    return p0 + s[..., None] * d1


def _detector(marker_map: MarkerMap, refine: str = "SUBPIX", win: int = 4) -> Any:
    import cv2

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = getattr(cv2.aruco, f"CORNER_REFINE_{refine}")
    params.cornerRefinementWinSize = win
    params.cornerRefinementMaxIterations = 50
    params.cornerRefinementMinAccuracy = 0.01
    return cv2.aruco.ArucoDetector(marker_map.aruco_dictionary(), params)


def detect_in_frame(image: np.ndarray, marker_map: MarkerMap, detector: Any = None, *,
                    refine: bool = True) -> np.ndarray:
    """(M, 4, 2) corners of the map's markers in one image (BGR or grey), NaN where not found (or found
    more than once: two markers with one id cannot be told apart). ``refine``: align each marker's
    whole pattern to the image (:func:`refine_corners`), not only its four corners."""
    import cv2

    detector = _detector(marker_map) if detector is None else detector
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _ = detector.detectMarkers(grey)
    out = np.full((len(marker_map), 4, 2), np.nan)
    if ids is None:
        return out
    index = {mid: k for k, mid in enumerate(marker_map.ids)}
    ids = ids.ravel()
    for c, mid in zip(corners, ids):
        if int(mid) in index and (ids == mid).sum() == 1:
            c = c.reshape(4, 2).astype(float)
            out[index[int(mid)]] = refine_corners(grey, c, marker_map, int(mid)) if refine else c
    return out


_TEMPLATES: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = {}


def _template(marker_map: MarkerMap, mid: int, px: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """(float32 image of the marker with a one-cell white margin, (4, 2) its black border's corners in
    the image's pixels, OpenCV's order)."""
    import cv2

    key = (marker_map.dictionary, mid)
    if key not in _TEMPLATES:
        d = marker_map.aruco_dictionary()
        cells = d.markerSize + 2
        img = cv2.aruco.generateImageMarker(d, mid, cells * px)
        img = cv2.copyMakeBorder(img, px, px, px, px, cv2.BORDER_CONSTANT, value=255).astype(np.float32)
        a, b = px - 0.5, (cells + 1) * px - 0.5  # cell edges: pixel centres are at integers
        _TEMPLATES[key] = (img, np.array([[a, a], [b, a], [b, b], [a, b]]))
    return _TEMPLATES[key]


def refine_corners(grey: np.ndarray, corners: np.ndarray, marker_map: MarkerMap, mid: int,
                   max_shift_px: float = 4.0) -> np.ndarray:
    """Corners (4, 2) of one marker refined by aligning its whole printed pattern (a homography, OpenCV's
    ``findTransformECC``, which is indifferent to brightness and contrast) to the image, started from
    ``corners``. Sub-pixel corner refinement alone looks at a small window round each corner; where a
    black cell of the pattern meets the border there, it has no corner to find, and on small markers
    seen obliquely it was up to 1.7 px off on rendered frames. Falls back to ``corners`` when the
    alignment fails or moves a corner more than ``max_shift_px``."""
    import cv2

    tmpl, tc = _template(marker_map, mid)
    H = cv2.getPerspectiveTransform(tc.astype(np.float32), corners.astype(np.float32)).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    try:
        _, H = cv2.findTransformECC(tmpl, grey.astype(np.float32), H, cv2.MOTION_HOMOGRAPHY, crit, None, 1)
    except cv2.error:
        return corners
    new = cv2.perspectiveTransform(tc.reshape(-1, 1, 2).astype(np.float64), H.astype(np.float64)).reshape(4, 2)
    if not np.isfinite(new).all() or np.abs(new - corners).max() > max_shift_px:
        return corners
    return new


def detect_markers(video: str | os.PathLike, marker_map: MarkerMap | str | os.PathLike, *,
                   progress: bool = False) -> MarkerTracks:
    """Find the map's markers in every frame of ``video`` (a video file or a folder of images).

    ``progress`` shows a progress bar (rich). Returns :class:`MarkerTracks`; raises
    :class:`ChainspaceError` when the video cannot be read or holds no frame.
    """
    mmap = marker_map if isinstance(marker_map, MarkerMap) else load_marker_map(marker_map)
    det = _detector(mmap)
    found = []
    # a folder of images states no rate: 30 fps, as before (detection does not use it)
    with open_video(video, fps=30.0 if Path(video).is_dir() else None) as frames, \
            progress_reporter(progress, frames.frame_count or 0, "detecting markers") as report:
        for k, im in enumerate(frames, 1):
            found.append(detect_in_frame(im, mmap, det))
            report(k)
    fps, size = frames.fps, frames.size
    if not found:
        raise ChainspaceError(f"{video}: the video holds no frame")
    corners = np.stack(found)
    centres = centre_of(corners)
    conf = np.isfinite(centres).all(-1).astype(float)
    return MarkerTracks(corners, centres, conf, mmap.names, fps, size, mmap)


def save_marker_tracks(path: str | os.PathLike, found: MarkerTracks, *, overwrite: bool = False,
                       seen_only: bool = True) -> Path:
    """Write the markers' centre tracks in the tracks CSV layout (``frame, joint, x, y, confidence``;
    :func:`chainspace.load_tracks` reads it); ``seen_only`` leaves out markers never seen."""
    from ..io.tracks import save_tracks

    keep = [k for k, n in enumerate(found.names) if not seen_only or n in set(found.seen)]
    if not keep:
        raise ChainspaceError("no marker was found in any frame: nothing to write")
    return save_tracks(path, found.centres[:, keep], [found.names[k] for k in keep],
                       confidence=found.confidence[:, keep], overwrite=overwrite)
