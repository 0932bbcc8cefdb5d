"""Rendered video of a URDF robot moving along known joint angles, through a pinhole camera, with truth.

The renderer is pybullet's CPU renderer (``ER_TINY_RENDERER`` in a ``DIRECT`` session: no GL, no display,
no system package; ``pip install -e .[test]`` or ``.[video]`` installs it). Each link gets a noise texture
in its URDF colour (so a point tracker has something to lock onto), the scene a textured floor and one
light; ArUco markers of a :class:`~chainspace.video.markers.MarkerMap` are thin plates (the marker with a
white margin in front, white behind) posed every frame from the link poses of Pinocchio's forward
kinematics, in the same URDF frames the chain and the fit use.

The camera: a :class:`chainspace.cameras.PinholeCamera` (its K, lens distortion and image size) and a
pose ``x_cam = R @ x_base + t`` (metres; OpenCV axes: x right, y down, z forward). Intrinsics become
an OpenGL projection with pixel centres at integers, as OpenCV has them. Frames are rendered
``supersample`` times larger and averaged down (``cv2.INTER_AREA``): edges are anti-aliased, which the
marker corners' sub-pixel accuracy needs. Lens distortion: the undistorted image is rendered (on a
canvas large enough to cover the distorted field) and warped with ``cv2.remap``, each output pixel
taking the undistorted pixel of its ray (:meth:`PinholeCamera.undistort`).

:func:`render_video` writes an MP4 (``mp4v``) or a folder of PNGs
(:func:`~chainspace.video.writer.frame_writer`), and a truth NPZ beside it (:func:`truth_path`): ``q``
(F, nq), ``K``, ``dist``, ``R``, ``t``, ``image_size``, ``fps``, ``points`` (F, J, 2) px and
``positions`` (F, J, 3) m of the chain's points (the URDF's tracked points), ``point_names``,
``marker_ids``, ``marker_corners`` (F, M, 4, 2) px and ``marker_visible`` (F, M), all
through the same camera (distortion included). Everything is a function of the inputs and ``seed``
(textures), so a cached clip is reproducible from the repository. :func:`render_trial` renders a
:class:`~chainspace.synthetic.robot.RobotTrial` filmed by ``synthesize(camera="pinhole", ...)``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ChainspaceError
from ..progress import progress_reporter

__all__ = ["RobotRenderer", "render_video", "render_trial", "truth_path", "load_truth", "RenderResult"]

_NEAR, _FAR = 0.05, 100.0  # clipping planes, metres


def truth_path(video: str | os.PathLike) -> Path:
    """The truth NPZ written beside a rendered video: ``clip.mp4`` -> ``clip.truth.npz``."""
    p = Path(video)
    return p.with_name((p.stem if p.suffix else p.name) + ".truth.npz")


def load_truth(video: str | os.PathLike) -> dict[str, np.ndarray]:
    """The truth of a rendered video (see the module docstring) as a dict of arrays."""
    with np.load(truth_path(video), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def projection_matrix(fx: float, fy: float, cx: float, cy: float, w: int, h: int) -> list[float]:
    """OpenGL projection (column-major, 16 floats) of a pinhole camera whose view matrix maps to OpenGL
    axes (x right, y up, z backward), for pybullet's tiny renderer: a point of OpenCV pixel (u, v) lands
    in pixel column u, row v (rows top-down). The tiny renderer samples each pixel at its lower-left
    corner in OpenGL's bottom-up rows, not at its centre (measured: marker corners came out half a
    pixel right and up with the centre convention), hence ``cx`` and ``cy + 1`` where OpenGL's
    centre-sampling formula has ``cx + 0.5`` and ``cy + 0.5``."""
    n, f = _NEAR, _FAR
    P = np.array([[2 * fx / w, 0, 1 - 2 * cx / w, 0],
                  [0, 2 * fy / h, 2 * (cy + 1.0) / h - 1, 0],
                  [0, 0, -(f + n) / (f - n), -2 * f * n / (f - n)],
                  [0, 0, -1, 0]])
    return P.T.ravel().tolist()


def view_matrix(R: np.ndarray, t: np.ndarray) -> list[float]:
    """OpenGL view matrix (column-major) of the OpenCV camera pose ``x_cam = R x + t``."""
    V = np.eye(4)
    V[:3, :3], V[:3, 3] = R, t
    V = np.diag([1.0, -1.0, -1.0, 1.0]) @ V  # OpenCV (y down, z forward) -> OpenGL (y up, z back)
    return V.T.ravel().tolist()


def _noise_texture(rng: np.random.Generator, rgb: np.ndarray, size: int = 256) -> np.ndarray:
    """(size, size, 3) uint8 RGB: blotchy noise (several scales, so it shows at any distance) around
    ``rgb`` (0..1), from dark to light, so the link keeps its colour."""
    import cv2

    noise = np.zeros((size, size))
    for cells, weight in ((8, 0.5), (32, 0.3), (128, 0.2)):
        n = rng.random((cells, cells))
        noise += weight * cv2.resize(n, (size, size), interpolation=cv2.INTER_CUBIC)
    noise = (noise - noise.min()) / max(np.ptp(noise), 1e-9)
    shade = 0.45 + 0.75 * noise
    return np.clip(255 * np.clip(rgb, 0.08, 1)[None, None] * shade[..., None], 0, 255).astype(np.uint8)


def _floor_texture(rng: np.random.Generator, size: int = 1024, tiles: int = 16) -> np.ndarray:
    """A grey tiled floor with noise (the background a point tracker and a viewer can see moving past)."""
    import cv2

    y, x = np.mgrid[:size, :size] * tiles // size
    base = np.where((x + y) % 2 == 0, 150, 110).astype(float)
    n = cv2.resize(rng.random((size // 4, size // 4)), (size, size), interpolation=cv2.INTER_LINEAR)
    g = np.clip(base + 60 * (n - 0.5) + 20 * (rng.random((size, size)) - 0.5), 0, 255)
    return np.repeat(g[..., None], 3, axis=2).astype(np.uint8)


def _marker_texture(marker_map: Any, mid: int, px_per_cell: int = 16) -> tuple[np.ndarray, float]:
    """RGB texture of a marker with a white margin of one cell each side, and the plate's side as a
    multiple of the marker's (margin included)."""
    import cv2

    d = marker_map.aruco_dictionary()
    cells = d.markerSize + 2  # the black border is one cell
    img = cv2.aruco.generateImageMarker(d, int(mid), cells * px_per_cell)
    img = cv2.copyMakeBorder(img, px_per_cell, px_per_cell, px_per_cell, px_per_cell, cv2.BORDER_CONSTANT,
                             value=255)
    return np.repeat(img[..., None], 3, axis=2), (cells + 2) / cells


def _plate_mesh(h: float, n: int) -> tuple[list, list, list, list]:
    """A marker plate of half side ``h`` (metres): the front (normal +z) an n x n grid of squares, one per
    cell of the marker (border and white margin included), the back a white square 2 mm behind. The
    tiny renderer maps textures affinely in screen space, not perspective-correctly: with one quad for
    the whole marker its inner corners came out up to 1.7 px off under oblique views. On a grid whose
    lines are the cell edges every square is one colour, and each cell corner is a vertex, exact."""
    g = np.linspace(-h, h, n + 1)
    x, y = np.meshgrid(g, g)
    u, w = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    verts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    uvs = np.column_stack([u.ravel(), w.ravel()])
    k = np.arange(n * (n + 1)).reshape(n, n + 1)[:, :n].ravel()  # lower-left vertex of each square
    tris = np.column_stack([k, k + 1, k + n + 2, k, k + n + 2, k + n + 1]).ravel()
    back0 = len(verts)
    verts = np.vstack([verts, [[-h, -h, -0.002], [h, -h, -0.002], [h, h, -0.002], [-h, h, -0.002]]])
    uvs = np.vstack([uvs, np.full((4, 2), 0.01)])  # a texel of the white margin
    tris = np.concatenate([tris, back0 + np.array([0, 2, 1, 0, 3, 2])])
    normals = [[0, 0, 1]] * back0 + [[0, 0, -1]] * 4
    return verts.tolist(), uvs.tolist(), tris.tolist(), normals


@dataclass
class RenderResult:
    """What :func:`render_video` wrote: ``video`` (MP4 or PNG folder), ``truth`` (NPZ), ``n_frames``,
    ``image_size`` (w, h), ``seconds_per_frame`` (rendering alone, wall time)."""

    video: Path
    truth: Path
    n_frames: int
    image_size: tuple[int, int]
    seconds_per_frame: float


@contextlib.contextmanager
def _quiet_c_output():
    """Silence what pybullet's C++ code prints on file descriptors 1 and 2 (its build date; "No inertial
    data for link ..." for every massless link, about physics, which rendering does not use)."""
    import ctypes
    import sys

    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    sys.stderr.flush()
    libc.fflush(None)
    saved = [os.dup(fd) for fd in (1, 2)]
    try:
        with open(os.devnull, "wb") as null:
            for fd in (1, 2):
                os.dup2(null.fileno(), fd)
            yield
            libc.fflush(None)  # C's buffered output goes to /dev/null, not to the terminal at exit
    finally:
        for fd, copy in zip((1, 2), saved):
            os.dup2(copy, fd)
            os.close(copy)


class RobotRenderer:
    """A pybullet scene of one robot (and its markers) seen by one pinhole camera.

    ``urdf_or_chain``: a URDF path or a chain made by :func:`chainspace.from_urdf` (its points are the
    ones whose truth is written). ``camera``: a :class:`~chainspace.cameras.PinholeCamera` with its image
    size; ``R``, ``t``: its pose (``x_cam = R x_base + t``, metres). ``markers``: a
    :class:`~chainspace.video.markers.MarkerMap` (or its file) or None. ``seed``: the textures.
    ``supersample``: render this many times larger and average down. ``floor_z``: floor height
    (metres; default the lowest point of the robot's visuals at rest, else 0). Use as a context
    manager (the pybullet session is closed on exit) or call :meth:`close`.
    """

    def __init__(self, urdf_or_chain: Any, camera: Any, R: Any, t: Any, *, markers: Any = None, seed: int = 0,
                 supersample: int = 2, floor: bool = True, shadow: bool = True,
                 light_direction: tuple[float, float, float] = (0.4, -0.6, 1.0)) -> None:
        import pinocchio as pin

        with _quiet_c_output():  # its build date, printed on import
            import pybullet as p

        from ..cameras.pinhole import as_camera
        from ..io.urdf import from_urdf, pinocchio_model
        from .markers import MarkerMap, load_marker_map

        self.chain = urdf_or_chain if hasattr(urdf_or_chain, "metadata") else from_urdf(urdf_or_chain)
        self.urdf = Path(self.chain.metadata["urdf_path"])
        self.camera = as_camera(camera)
        if self.camera is None or self.camera.image_size is None:
            raise ChainspaceError("rendering needs a pinhole camera with its image size (width, height)")
        self.R = np.asarray(R, float).reshape(3, 3)
        self.t = np.asarray(t, float).reshape(3)
        self.markers = (markers if markers is None or isinstance(markers, MarkerMap)
                        else load_marker_map(markers, urdf=self.urdf))
        self.supersample = int(supersample)
        self.shadow, self.light_direction = bool(shadow), list(light_direction)
        self.model = pinocchio_model(self.chain)
        self.data = self.model.createData()
        self._pin = pin
        self._p = p
        with _quiet_c_output():
            self.cid = p.connect(p.DIRECT)
        self._tmp = tempfile.TemporaryDirectory(prefix="chainspace-render-")
        try:
            self._build(np.random.default_rng(seed), floor)
        except Exception:
            self.close()
            raise
        self._setup_camera()

    # ------------------------------------------------------------------------------- scene
    def _texture(self, name: str, rgb: np.ndarray) -> int:
        import cv2

        path = os.path.join(self._tmp.name, f"{name}.png")
        cv2.imwrite(path, rgb[..., ::-1])
        return self._p.loadTexture(path, physicsClientId=self.cid)

    def _build(self, rng: np.random.Generator, floor: bool) -> None:
        p, cid = self._p, self.cid
        # pybullet resolves package:// and relative mesh paths against the URDF's folder and its search path
        p.setAdditionalSearchPath(str(self.urdf.parent), physicsClientId=cid)
        try:
            with _quiet_c_output():
                self.body = p.loadURDF(str(self.urdf), useFixedBase=True,
                                       flags=p.URDF_USE_MATERIAL_COLORS_FROM_MTL, physicsClientId=cid)
        except p.error as exc:
            raise ChainspaceError(f"{self.urdf}: pybullet cannot load this URDF for rendering ({exc})") from None
        # joints pybullet moves -> their coordinate in Pinocchio's q (continuous joints: angle from cos, sin)
        self._joints = []
        for j in range(p.getNumJoints(self.body, physicsClientId=cid)):
            info = p.getJointInfo(self.body, j, physicsClientId=cid)
            name = info[1].decode()
            if info[2] == p.JOINT_FIXED or not self.model.existJointName(name):
                continue
            jm = self.model.joints[self.model.getJointId(name)]
            if jm.nq in (1, 2):
                self._joints.append((j, jm.idx_q, jm.nq))
        colours = {}
        for vis in p.getVisualShapeData(self.body, physicsClientId=cid):
            colours.setdefault(vis[1], np.asarray(vis[7][:3]))
        for link, rgb in colours.items():
            tex = self._texture(f"link{link}", _noise_texture(rng, rgb))
            p.changeVisualShape(self.body, link, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=cid)
        reach = float(np.linalg.norm(np.ptp(self.chain.rest_pose, axis=0))) + 1.0
        if floor:
            half = 3.0 * reach
            vs = p.createVisualShape(p.GEOM_BOX, halfExtents=[half, half, 0.005], rgbaColor=[1, 1, 1, 1],
                                     physicsClientId=cid)
            self.floor = p.createMultiBody(0, -1, vs, basePosition=[0, 0, -0.0051], physicsClientId=cid)
            p.changeVisualShape(self.floor, -1, textureUniqueId=self._texture("floor", _floor_texture(rng)),
                                physicsClientId=cid)
        self._marker_bodies = []
        if self.markers is not None:
            half = self.markers.aruco_dictionary().markerSize / 2 + 1  # half the marker, in cells
            self._margin_mid = (half + 0.5) / half
            for m in self.markers.markers:
                tex_img, scale = _marker_texture(self.markers, m.id)
                v, uv, idx, nrm = _plate_mesh(0.5 * m.size * scale, self.markers.aruco_dictionary().markerSize + 4)
                vs = p.createVisualShape(p.GEOM_MESH, vertices=v, indices=idx, uvs=uv, normals=nrm,
                                         physicsClientId=cid)
                b = p.createMultiBody(0, -1, vs, physicsClientId=cid)
                p.changeVisualShape(b, -1, textureUniqueId=self._texture(f"marker{m.id}", tex_img),
                                    rgbaColor=[1, 1, 1, 1], physicsClientId=cid)
                frame = self.model.getFrameId(m.link, self._pin.FrameType.BODY)
                self._marker_bodies.append((b, frame, m.rotation(), np.asarray(m.xyz)))

    def _setup_camera(self) -> None:
        cam = self.camera
        w, h = cam.image_size
        self._pad = (0, 0)
        self._map = None
        if cam.has_distortion:
            # each output (distorted) pixel samples the undistorted image where its ray lands
            u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
            src = cam.undistort(np.stack([u, v], -1))
            lo = np.nanmin(src.reshape(-1, 2), 0)
            hi = np.nanmax(src.reshape(-1, 2), 0)
            pad = np.ceil(np.maximum(np.maximum(-lo, hi - [w - 1, h - 1]), 0)).astype(int) + 2
            pad = np.minimum(pad, [w, h])  # a strong fold of the lens model would ask for a huge canvas
            self._pad = (int(pad[0]), int(pad[1]))
            self._map = (src + pad).astype(np.float32)
        pw, ph = self._pad
        W, H = w + 2 * pw, h + 2 * ph
        s = self.supersample
        # the supersampled camera: averaging s x s blocks back down gives the camera's own pixels
        fx, fy = cam.fx * s, cam.fy * s
        cx, cy = (cam.cx + pw + 0.5) * s - 0.5, (cam.cy + ph + 0.5) * s - 0.5
        self._size = (W * s, H * s)
        self._proj = projection_matrix(fx, fy, cx, cy, W * s, H * s)
        self._view = view_matrix(self.R, self.t)

    def close(self) -> None:
        if getattr(self, "cid", None) is not None:
            try:
                self._p.disconnect(self.cid)
            except self._p.error:
                pass
            self.cid = None
        if getattr(self, "_tmp", None) is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> RobotRenderer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------------------- frames
    def pose(self, q: np.ndarray) -> None:
        """Move the robot (and its markers) to configuration ``q`` (nq,), Pinocchio order."""
        p, cid = self._p, self.cid
        q = np.asarray(q, float)
        for j, iq, nq in self._joints:
            value = q[iq] if nq == 1 else np.arctan2(q[iq + 1], q[iq])
            p.resetJointState(self.body, j, float(value), physicsClientId=cid)
        if self._marker_bodies:
            self._pin.framesForwardKinematics(self.model, self.data, q)
            for b, frame, Rm, xyz in self._marker_bodies:
                oMf = self.data.oMf[frame]
                pos = oMf.rotation @ xyz + oMf.translation
                quat = self._pin.Quaternion(oMf.rotation @ Rm)
                p.resetBasePositionAndOrientation(b, pos.tolist(), [quat.x, quat.y, quat.z, quat.w],
                                                  physicsClientId=cid)

    def render(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(BGR image (h, w, 3) uint8, segmentation (h, w) int: pybullet body id per pixel, -1 for none, at
        the camera's own size, undistorted canvas without lens distortion) at configuration ``q``."""
        import cv2

        p = self._p
        self.pose(q)
        W, H = self._size
        _, _, rgba, _, seg = p.getCameraImage(
            W, H, self._view, self._proj, renderer=p.ER_TINY_RENDERER, shadow=int(self.shadow),
            lightDirection=self.light_direction, lightColor=[1, 1, 1], lightDistance=20.0,
            lightAmbientCoeff=0.45, lightDiffuseCoeff=0.6, lightSpecularCoeff=0.15, physicsClientId=self.cid)
        rgb = np.asarray(rgba, np.uint8).reshape(H, W, 4)[..., :3]
        seg = np.asarray(seg).reshape(H, W)
        s = self.supersample
        if s > 1:
            rgb = cv2.resize(rgb, (W // s, H // s), interpolation=cv2.INTER_AREA)
            seg = seg[s // 2 :: s, s // 2 :: s]
        if self._map is not None:
            rgb = cv2.remap(rgb, self._map[..., 0], self._map[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            seg = cv2.remap(seg.astype(np.float32), self._map[..., 0], self._map[..., 1], cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=-1).astype(int)
        return np.ascontiguousarray(rgb[..., ::-1]), seg

    # ------------------------------------------------------------------------------- truth
    def truth(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Truth of configurations ``q`` (F, nq): ``positions`` (F, J, 3) m and ``points`` (F, J, 2) px of
        the chain's points, ``marker_corners`` (F, M, 4, 2) px and ``marker_facing`` (F, M) (the
        marker's normal within 60 degrees of the line to the camera: more oblique, a marker is hard to
        decode and it is not counted as seen)."""
        from ..io.urdf import point_positions
        from .markers import marker_corners_local

        q = np.atleast_2d(np.asarray(q, float))
        pos = point_positions(self.chain, q)
        out = {"positions": pos, "points": self.camera.project(pos @ self.R.T + self.t)}
        M = len(self._marker_bodies)
        corners = np.full((len(q), M, 4, 2), np.nan)
        facing = np.zeros((len(q), M), bool)
        centre = -self.R.T @ self.t
        for f, qf in enumerate(q):
            self._pin.framesForwardKinematics(self.model, self.data, qf)
            for k, (m, (_, frame, Rm, xyz)) in enumerate(zip(self.markers.markers if M else [], self._marker_bodies)):
                oMf = self.data.oMf[frame]
                Rw = oMf.rotation @ Rm
                cw = oMf.rotation @ xyz + oMf.translation
                pts = marker_corners_local(m.size) @ Rw.T + cw
                corners[f, k] = self.camera.project(pts @ self.R.T + self.t)
                look = centre - cw
                facing[f, k] = Rw[:, 2] @ look > np.cos(np.deg2rad(60)) * np.linalg.norm(look)
        out["marker_corners"] = corners
        out["marker_facing"] = facing
        return out

    def visible(self, corners: np.ndarray, facing: np.ndarray, seg: np.ndarray) -> np.ndarray:
        """(M,) markers of one frame seen whole: facing the camera, inside the image (2 px in), and the marker's own
        plate at each corner and edge midpoint of its black border (pulled 5 % in) and of its white
        margin (nothing in front of it)."""
        h, w = seg.shape
        out = np.zeros(len(self._marker_bodies), bool)
        for k, (b, *_rest) in enumerate(self._marker_bodies):
            c = corners[k]
            if not facing[k] or not np.isfinite(c).all():
                continue
            # the black border's corners and edge midpoints pulled 5 % in, and the same points in the
            # middle of the white margin round it (cv2.aruco needs that quiet zone clear to find it)
            rim = np.vstack([c, 0.5 * (c + np.roll(c, -1, axis=0))])
            mid = c.mean(0)
            inner = np.rint(np.vstack([rim + 0.05 * (mid - rim), mid + (rim - mid) * self._margin_mid])).astype(int)
            if (c < 2).any() or (c[:, 0] > w - 3).any() or (c[:, 1] > h - 3).any():
                continue  # cut by the image border (or touching it: cv2.aruco drops those)
            out[k] = bool((seg[inner[:, 1], inner[:, 0]] == b).all())
        return out


def render_video(urdf_or_chain: Any, q: Any, camera: Any, R: Any, t: Any, out: str | os.PathLike, *,
                 fps: float = 30.0, markers: Any = None, seed: int = 0, supersample: int = 2,
                 overwrite: bool = False, progress: bool = False, **scene: Any) -> RenderResult:
    """Render the robot at joint angles ``q`` (F, nq; Pinocchio order, radians/metres) through ``camera``
    posed at ``R``, ``t`` into ``out`` (``.mp4``: an MP4 video; a path without suffix: a folder of
    ``frame_00000.png``...), with the truth NPZ beside it (:func:`truth_path`; see the module
    docstring). ``markers``: a marker map (or its file) whose markers are drawn on the links. Refuses
    to replace files unless ``overwrite``; writes the video and the truth through temporary names
    renamed into place. ``scene``: passed to :class:`RobotRenderer` (``floor``, ``shadow``,
    ``light_direction``). Returns a :class:`RenderResult`.
    """
    from ..io.results import atomic_write, check_writable
    from .writer import frame_writer

    out = Path(out)
    tpath = truth_path(out)
    check_writable([out, tpath], overwrite)
    q = np.atleast_2d(np.asarray(q, float))
    if not np.isfinite(q).all():
        raise ChainspaceError("the joint angles to render hold NaN or infinite values")
    with RobotRenderer(urdf_or_chain, camera, R, t, markers=markers, seed=seed, supersample=supersample,
                       **scene) as r:
        w, h = r.camera.image_size
        truth = r.truth(q)
        visible = np.zeros(truth["marker_facing"].shape, bool)
        spent = 0.0
        with frame_writer(out, fps, (w, h), overwrite=overwrite) as writer, \
                progress_reporter(progress, len(q), f"rendering {out.name}") as report:
            for f in range(len(q)):
                report(f)
                t0 = time.perf_counter()
                img, seg = r.render(q[f])
                spent += time.perf_counter() - t0
                visible[f] = r.visible(truth["marker_corners"][f], truth["marker_facing"][f], seg)
                writer.write(img)
            report(len(q))
        cam = r.camera
        arrays = dict(q=q, K=cam.K, dist=cam.dist, R=r.R, t=r.t, image_size=np.array([w, h]), fps=np.array(fps),
                      points=truth["points"], positions=truth["positions"],
                      point_names=np.array(list(r.chain.joints)),
                      marker_ids=np.array(r.markers.ids if r.markers else [], int),
                      marker_corners=truth["marker_corners"], marker_visible=visible, seed=np.array(seed),
                      supersample=np.array(supersample))
        with atomic_write(tpath, "wb", overwrite) as fh:
            np.savez_compressed(fh, **arrays)
    return RenderResult(out, tpath, len(q), (w, h), spent / len(q))


def render_trial(trial: Any, out: str | os.PathLike, **kwargs: Any) -> RenderResult:
    """Render a :class:`~chainspace.synthetic.robot.RobotTrial` filmed through a pinhole camera
    (``synthesize(..., camera="pinhole")``): its joint angles, camera and pose. ``kwargs``: as
    :func:`render_video` (``markers``, ``seed``, ``supersample``, ``overwrite``, ...)."""
    if trial.intrinsics is None or trial.camera_R is None:
        raise ChainspaceError("render_trial needs a trial filmed through a pinhole camera: "
                              "synthesize(..., camera='pinhole')")
    cam = trial.intrinsics
    if cam.image_size is None:
        cam = cam.with_size(*trial.image_size)
    kwargs.setdefault("fps", trial.fps)
    return render_video(trial.chain, trial.q, cam, trial.camera_R, trial.camera_t, out, **kwargs)
