"""See a motion in 3D: meshcat animations, live or as one standalone HTML file.

A chain is drawn as spheres at the joints and cylinders for the bones; a robot fit is drawn with the
robot's own visual geometry (Pinocchio's ``MeshcatVisualizer`` on the URDF's visual model) driven by the
fitted joint angles, with the reconstructed points over it. The ground truth, when given, stands beside
the reconstruction in another colour.

The motion lives on meshcat's animation timeline (play, pause, scrub in the "Animations" panel). Only
*transforms* are animated: every joint, bone and robot part is created once and then moved per frame
(a bone is one cylinder, placed, turned and, if its length varies, stretched per frame), so the HTML
grows by a few hundred bytes per frame and part, not by a mesh per frame. :func:`write_html` writes the
static HTML meshcat's server would (``Visualizer.static_html``: meshcat's JavaScript inlined, the scene as
base64 msgpack) without starting a server, so writing a file opens no port and needs no network, and the
file opens in a browser from disk with no server and no network.

World frame: Z up, metres. A human reconstruction (its own camera-centred frame) is turned upright by
aligning it to the truth when given, else to the chain's rest pose, else by assuming image y points
down; each skeleton is centred on its root every frame and stands on z = 0.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CameraError, TrackError
from ..io.results import atomic_write

__all__ = ["write_html", "show", "build_scene", "upright_poses", "frustum_corners"]

COLORS = {"reconstruction": 0x1F77B4, "truth": 0x2CA02C, "points": 0xD62728, "camera": 0x333333}


class _Reply:
    """Stands in for the ZMQ socket through which meshcat's server answers."""

    data = b""

    def send(self, data: bytes) -> None:
        self.data = data


class _OfflineWindow:
    """A meshcat window without a server: meshcat's own server code keeps the scene tree and renders
    the static HTML, fed directly instead of over ZMQ. Floats are packed in single precision, which
    halves the animation data (positions to about a micrometre)."""

    web_url = None

    def __init__(self) -> None:
        _import_meshcat()
        from meshcat.servers.tree import SceneTree
        from meshcat.servers.zmqserver import ZMQWebSocketBridge

        self._bridge = ZMQWebSocketBridge.__new__(ZMQWebSocketBridge)  # no sockets, no ports
        self._bridge.tree = SceneTree()
        self._bridge.websocket_pool = set()
        self._bridge.zmq_socket = self._reply = _Reply()

    def send(self, command: Any) -> None:
        import umsgpack

        data = command.lower()
        packed = umsgpack.packb(data, force_float_precision="single")
        self._bridge.handle_zmq([data["type"].encode(), data["path"].encode(), packed])

    def get_scene(self) -> str:
        self._bridge.handle_zmq([b"get_scene"])
        return self._reply.data.decode("utf-8")


def _import_meshcat() -> Any:
    import warnings

    with warnings.catch_warnings():  # meshcat 0.3.2 imports a pyzmq module deprecated since pyzmq 17
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat
    return meshcat


def _offline_visualizer() -> Any:
    return _import_meshcat().Visualizer(window=_OfflineWindow())


# ---------------------------------------------------------------------------------------- geometry
def _y_to(v: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions [x, y, z, w] turning the +Y axis (meshcat's cylinder axis) onto unit ``v``."""
    w = 1.0 + v[..., 1]
    q = np.stack([v[..., 2], np.zeros_like(w), -v[..., 0], w], axis=-1)
    flip = w < 1e-9  # v = -Y: half a turn about X
    q[flip] = [1.0, 0.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _check_poses(poses: Any, n_joints: int | None, what: str) -> np.ndarray:
    try:
        X = np.array(poses, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrackError(f"{what} are not numeric: {exc}") from None
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] == 0 or (n_joints is not None and X.shape[1] != n_joints):
        want = f"(frames, {n_joints}, 3)" if n_joints else "(frames, joints, 3)"
        raise TrackError(f"{what} have shape {X.shape}, expected {want}")
    bad = np.argwhere(~np.isfinite(X).all(axis=2))
    if len(bad):
        raise TrackError(f"{what}: joint {bad[0][1]} in frame {bad[0][0]} is not finite; the viewer needs "
                         "every joint in every frame")
    return X


def _track(name: str, jstype: str, values: np.ndarray) -> Any:
    from meshcat.animation import AnimationTrack

    return AnimationTrack(name, jstype, frames=list(range(len(values))), values=values.tolist())


def _clip(animation: Any, vis: Any, fps: float, **tracks: tuple[str, np.ndarray]) -> None:
    from meshcat.animation import AnimationClip

    clip = AnimationClip(fps=fps)
    for name, (jstype, values) in tracks.items():
        clip.tracks[name] = _track(name, jstype, values)
    animation.clips[vis.path] = clip


def add_skeleton(vis: Any, animation: Any, poses: np.ndarray, chain: Any, *, color: int, radius: float,
                 fps: float, opacity: float = 1.0) -> None:
    """Spheres at the joints and cylinders for the links of ``poses`` (F, J, 3) m under node ``vis``.

    Joint nodes carry a position track; each link's node hangs from its first joint's node and carries
    a rotation track (plus a stretch track when its length varies by more than 0.1 %).
    """
    import meshcat.geometry as g
    import meshcat.transformations as tf

    mat = g.MeshLambertMaterial(color=color, opacity=opacity, transparent=opacity < 1)
    bone_mat = g.MeshLambertMaterial(color=_lighter(color), opacity=opacity, transparent=opacity < 1)
    for j, name in enumerate(chain.joints):
        node = vis["joints"][name]
        node.set_object(g.Sphere(radius), mat)
        _clip(animation, node, fps, position=("vector3", poses[:, j]))
    ia = np.array([chain.joint_index(a) for a, _ in chain.links], dtype=int)
    ib = np.array([chain.joint_index(b) for _, b in chain.links], dtype=int)
    if not len(ia):
        return
    vec = poses[:, ib] - poses[:, ia]  # (F, L, 3)
    length = np.linalg.norm(vec, axis=-1)
    unit = np.divide(vec, length[..., None], out=np.tile([0.0, 1.0, 0.0], vec.shape[:2] + (1,)),
                     where=length[..., None] > 1e-12)
    quat = _y_to(unit)
    rest = np.maximum(np.median(length, axis=0), 1e-6)
    for k, (a, b) in enumerate(chain.links):
        # The bone hangs from joint a's node, so it moves with it and needs only a rotation track; its
        # cylinder sits half a length along the rotated Y axis, which a per-frame stretch also scales.
        node = vis["joints"][a][f"to_{b}"]
        node["mid"].set_transform(tf.translation_matrix([0.0, rest[k] / 2, 0.0]))
        node["mid"].set_object(g.Cylinder(float(rest[k]), 0.45 * radius), bone_mat)
        tracks = {"quaternion": ("quaternion", quat[:, k])}
        stretch = length[:, k] / rest[k]
        if np.abs(stretch - 1).max() > 1e-3:  # reconstructions keep bone lengths; other poses may not
            tracks["scale"] = ("vector3", np.stack([np.ones_like(stretch), stretch, np.ones_like(stretch)], -1))
        _clip(animation, node, fps, **tracks)


def _lighter(color: int) -> int:
    rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255], dtype=float)
    rgb = rgb + 0.35 * (255 - rgb)
    return int(rgb[0]) << 16 | int(rgb[1]) << 8 | int(rgb[2])


def add_robot(vis: Any, animation: Any, urdf_path: str | os.PathLike, q: np.ndarray, *, fps: float) -> Any:
    """The URDF's visual geometry under node ``vis``, moved by joint angles ``q`` (F, nq) per frame.

    Uses Pinocchio's MeshcatVisualizer to create the geometry once; the per-frame placements (forward
    kinematics, one Pinocchio call per frame) go onto the animation timeline as position and quaternion
    tracks. Returns the Pinocchio model.
    """
    import pinocchio as pin
    from pinocchio.visualize import MeshcatVisualizer
    from scipy.spatial.transform import Rotation

    urdf_path = Path(urdf_path)
    model, visual = _robot_models(urdf_path)
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != model.nq:
        raise TrackError(f"joint angles have shape {q.shape}, but {urdf_path.name} has nq = {model.nq}")
    viz = MeshcatVisualizer(model, None, visual)
    viz.initViewer(viewer=vis)
    viz.loadViewerModel(rootNodeName="robot")
    viz.display(q[0])  # sets each part's static transform, including any mesh scale
    data, vdata = model.createData(), visual.createData()
    F, G = len(q), len(visual.geometryObjects)
    pos, rot = np.empty((F, G, 3)), np.empty((F, G, 3, 3))
    for f in range(F):  # forward kinematics has no batched form in Pinocchio's Python API
        pin.forwardKinematics(model, data, q[f])
        pin.updateGeometryPlacements(model, data, visual, vdata)
        for i in range(G):
            pos[f, i] = vdata.oMg[i].translation
            rot[f, i] = vdata.oMg[i].rotation
    quat = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat().reshape(F, G, 4)  # [x, y, z, w]
    for i, obj in enumerate(visual.geometryObjects):
        node = vis[viz.getViewerNodeName(obj, pin.GeometryType.VISUAL)]
        _clip(animation, node, fps, position=("vector3", pos[:, i]), quaternion=("quaternion", quat[:, i]))
    return model


def frustum_corners(camera: Any, pose: Any, depth: float) -> np.ndarray:
    """(5, 3) the camera's centre and, at ``depth`` in front of it, where the rays through the image's
    four outer corners (top-left, top-right, bottom-right, bottom-left) reach; world units.

    ``camera`` is a :class:`chainspace.cameras.pinhole.PinholeCamera` with a known image size, ``pose``
    ``(R (3, 3), t (3,))`` maps world points into the camera frame (``x_cam = R x + t``), ``depth`` is
    along the optical axis (z in the camera frame). Lens distortion is undone, so the rays are the
    ones the corner pixels really see.
    """
    R, t = _pose(pose)
    if not depth > 0:
        raise CameraError(f"the frustum's depth must be positive, not {depth!r}")
    xy = camera.rays(camera.corners())  # (4, 2) normalised x/z, y/z
    cam = np.concatenate([np.zeros((1, 3)), np.column_stack([xy * depth, np.full(4, float(depth))])])
    return (cam - t) @ R  # x = R^T (x_cam - t), row-wise


def _pose(pose: Any) -> tuple[np.ndarray, np.ndarray]:
    try:
        R, t = (np.asarray(a, dtype=float) for a in pose)
    except (TypeError, ValueError):
        raise CameraError("camera_pose must be (R (3, 3), t (3,))") from None
    if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise CameraError(f"camera_pose must be a finite (R (3, 3), t (3,)), not shapes {R.shape}, {t.shape}")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise CameraError("camera_pose's R is not a rotation")
    return R, t


def add_frustum(vis: Any, corners: np.ndarray, *, color: int = COLORS["camera"]) -> None:
    """Line segments from the apex to the four corners and around them, ``corners`` (5, 3) as
    :func:`frustum_corners` gives, as the object of node ``vis``."""
    import meshcat.geometry as g

    apex, rim = corners[0], corners[1:]
    ends = [(apex, c) for c in rim] + [(rim[i], rim[(i + 1) % 4]) for i in range(4)]
    points = np.array([p for pair in ends for p in pair], dtype=np.float32).T  # (3, 16)
    vis.set_object(g.LineSegments(g.PointsGeometry(points), g.LineBasicMaterial(color=color, linewidth=2)))


def _base_positions(fit: Any, fallback: np.ndarray) -> np.ndarray:
    positions = getattr(fit, "positions_base", None)
    return fallback if positions is None else np.asarray(positions, dtype=float)


def _weak_pose(camera: Any, poses: np.ndarray | None, cameras: Any, translations: Any) -> tuple[np.ndarray, np.ndarray]:
    """The pinhole pose of frame 0's weak-perspective camera, about the subject's middle in that frame."""
    from ..cameras.pose import pose_from_weak

    if poses is None or cameras is None or translations is None:
        raise CameraError("drawing the camera needs camera_pose= (or a result with fitted cameras)")
    return pose_from_weak(np.asarray(cameras)[0], np.asarray(translations)[0], camera, poses[0].mean(axis=0))


def _robot_models(urdf_path: Path) -> tuple[Any, Any]:
    """Pinocchio's model and visual geometry of a URDF, its meshes found as ROS tools find them
    (:func:`chainspace.io.urdf.resolve_mesh`); missing meshes are drawn as primitives, with a warning."""
    import pinocchio as pin

    from ..io.urdf import build_model, visual_urdf

    model = build_model(urdf_path)  # mimic joints driven by their leader, as the fit's model
    xml = visual_urdf(urdf_path)
    dirs = [str(p) for p in list(urdf_path.resolve().parents)[:4]]
    visual = pin.buildGeomFromUrdfString(model, xml, pin.GeometryType.VISUAL, package_dirs=dirs)
    return model, visual


# ---------------------------------------------------------------------------------------- staging
def _upright(poses: np.ndarray, chain: Any, truth: np.ndarray | None, cameras: np.ndarray | None) -> np.ndarray:
    """Rotation (3, 3) turning a reconstruction's camera-centred frame Z-up."""
    from scipy.spatial.transform import Rotation

    root = chain.joint_index(chain.root) if chain is not None else 0
    X = (poses - poses[:, root:root + 1]).reshape(-1, 3)
    if truth is not None and truth.shape == poses.shape:
        Y = (truth - truth[:, root:root + 1]).reshape(-1, 3)
        return Rotation.align_vectors(Y, X)[0].as_matrix()
    rest = getattr(chain, "rest_pose", None)
    if rest is not None:
        Y = np.tile(rest - rest[root], (len(poses), 1))
        return Rotation.align_vectors(Y, X)[0].as_matrix()
    if cameras is not None:
        down = np.asarray(cameras, dtype=float)[:, 1]
        up = -np.mean(down / np.linalg.norm(down, axis=1, keepdims=True), axis=0)
        if np.linalg.norm(up) > 1e-9:
            return Rotation.align_vectors([[0, 0, 1]], [up])[0].as_matrix()
    return np.eye(3)


def _stand(poses: np.ndarray, root: int) -> np.ndarray:
    """Centre each frame on its root in x, y and put the lowest point of the sequence on z = 0."""
    out = poses.copy()
    out[..., :2] -= poses[:, root:root + 1, :2]
    out[..., 2] -= out[..., 2].min()
    return out


def upright_poses(rec_or_poses: Any, *, chain: Any = None, truth: Any = None) -> np.ndarray:
    """The poses (F, J, 3) as the viewer shows them: turned Z-up, root centred in x, y, feet on z = 0.

    Used to export a reconstruction (which lives in its camera's frame) as an upright BVH motion.
    """
    poses, chain, cameras = _unpack(rec_or_poses, chain)
    if chain is None:
        raise TrackError("poses need chain= to find the root")
    poses = _check_poses(poses, chain.n_joints, "poses")
    truth = None if truth is None else _check_poses(truth, chain.n_joints, "truth poses")
    return _stand(poses @ _upright(poses, chain, truth, cameras).T, chain.joint_index(chain.root))


def _extent(*pose_sets: np.ndarray) -> float:
    pts = np.concatenate([p.reshape(-1, 3) for p in pose_sets if p is not None])
    return float(np.max(np.ptp(pts, axis=0))) or 1.0


def _unpack(rec_or_poses: Any, chain: Any) -> tuple[np.ndarray | None, Any, np.ndarray | None]:
    if rec_or_poses is None:
        return None, chain, None
    if hasattr(rec_or_poses, "poses"):
        chain = chain if chain is not None else getattr(rec_or_poses, "chain", None)
        return np.asarray(rec_or_poses.poses), chain, getattr(rec_or_poses, "cameras", None)
    return np.asarray(rec_or_poses), chain, None


def build_scene(vis: Any, rec_or_poses: Any = None, *, chain: Any = None, truth: Any = None, fit: Any = None,
                fps: float | None = None, camera: Any = None, camera_pose: Any = None) -> Any:
    """Draw everything into meshcat visualizer ``vis`` and set the animation; return the Animation.

    ``rec_or_poses`` is a Reconstruction (or what :func:`chainspace.io.results.load_results` returns) or
    poses (F, J, 3) m with ``chain``. ``truth`` (F, J, 3) m is drawn beside it. ``fit`` (a JointFit)
    draws the robot from its URDF driven by ``fit.q``, with the reconstructed points (mapped into the
    robot's base frame by the fit's similarity) over it; ``truth`` is then in the base frame.

    ``camera`` (a :class:`chainspace.cameras.pinhole.PinholeCamera` with its image size) draws the
    camera's frustum (node ``chainspace/camera/frustum``) out to 0.3 of the scene's size.
    ``camera_pose`` ``(R, t)`` maps the scene's points (the robot's base frame with a fit, else the
    reconstruction's frame) into the camera frame, ``x_cam = R x + t``; by default it is frame 0's
    fitted weak-perspective camera seen as a pinhole with ``camera``'s intrinsics. ``fps`` (frames per
    second): by default the fit's own (:attr:`~chainspace.robot.result.JointFit.fps`), else 30.
    """
    from meshcat.animation import Animation

    from ..robot.result import playback_fps

    if hasattr(rec_or_poses, "q"):  # a JointFit passed first
        fit, rec_or_poses = fit if fit is not None else rec_or_poses, None
    poses, chain, cameras = _unpack(rec_or_poses, chain)
    if poses is None and fit is None:
        raise TrackError("nothing to show: give a reconstruction, poses (with chain=) or a fit")
    if poses is not None and chain is None:
        raise TrackError("poses need chain= to know which joints the bones join")
    if poses is not None:
        poses = _check_poses(poses, chain.n_joints, "poses")
    truth = None if truth is None else _check_poses(truth, None, "truth poses")
    fps = playback_fps(fit, fps)
    animation = Animation(default_framerate=fps)
    scene = vis["chainspace"]
    if camera is not None:
        from ..cameras.pinhole import as_camera

        camera = as_camera(camera)
        if camera.image_size is None:
            raise CameraError("drawing the camera needs its image size (width, height)")

    if fit is not None:
        add_robot(scene, animation, fit.urdf_path, fit.q, fps=fps)
        if poses is None:
            poses, chain = np.asarray(fit.positions), fit.chain
        if len(poses) != len(fit.q) or (truth is not None and len(truth) != len(fit.q)):
            raise TrackError(f"the fit has {len(fit.q)} frames, the reconstruction {len(poses)}"
                             + ("" if truth is None else f" and the truth {len(truth)}"))
        # reconstruction frame -> robot base frame: x_base = R^T (x - t) / s
        base = np.einsum("ij,fki->fkj", np.asarray(fit.rotation), poses - np.asarray(fit.translation))
        base /= float(fit.scale)
        size = float(np.ptp(base, axis=1).max()) or 1.0  # the robot's size in any one frame
        add_skeleton(scene["reconstruction"], animation, base, chain, color=COLORS["points"],
                     radius=0.012 * size, fps=fps, opacity=0.9)
        if truth is not None:
            if truth.shape[1] != chain.n_joints:
                raise TrackError(f"truth has {truth.shape[1]} joints, the fit's chain {chain.n_joints}")
            # beside the robot along its reach, so that the camera (broadside to the reach) sees both
            shift = 1.1 * size * np.append(_principal_axis(base.reshape(-1, 3)), 0.0)
            add_skeleton(scene["truth"], animation, truth + shift, chain, color=COLORS["truth"],
                         radius=0.012 * size, fps=fps)
        shown = base.reshape(-1, 3) if truth is None else np.concatenate([base, truth + shift]).reshape(-1, 3)
        if camera is not None:
            pose = camera_pose if camera_pose is not None else \
                _weak_pose(camera, _base_positions(fit, base), getattr(fit, "cameras", None),
                           getattr(fit, "translations_2d", None))
            add_frustum(scene["camera"]["frustum"], frustum_corners(camera, pose, 0.3 * size))
    else:
        if truth is not None and truth.shape != poses.shape:
            raise TrackError(f"truth has shape {truth.shape}, the poses {poses.shape}")
        root = chain.joint_index(chain.root)
        R = _upright(poses, chain, truth, cameras)
        turned = poses @ R.T
        shown = _stand(turned, root)
        size = _extent(shown)
        if camera is not None:
            pose = camera_pose if camera_pose is not None else \
                _weak_pose(camera, poses, cameras, getattr(rec_or_poses, "translations", None))
            # the skeleton is turned upright and re-centred every frame; the camera moves with it
            node = scene["camera"]
            add_frustum(node["frustum"], frustum_corners(camera, pose, 0.3 * size) @ R.T)
            _clip(animation, node, fps, position=("vector3", (shown - turned)[:, 0]))
        add_skeleton(scene["reconstruction"], animation, shown, chain, color=COLORS["reconstruction"],
                     radius=0.02 * size, fps=fps)
        if truth is not None:
            staged = _stand(truth, root) + [0.0, 0.8 * size, 0.0]
            add_skeleton(scene["truth"], animation, staged, chain, color=COLORS["truth"],
                         radius=0.02 * size, fps=fps)
            shown = np.concatenate([shown, staged], axis=1)
    _frame_camera(vis, shown.reshape(-1, 3))
    vis.set_animation(animation, play=True, repetitions=float("inf"))
    return animation


def _principal_axis(points: np.ndarray) -> np.ndarray:
    """(2,) unit horizontal direction along which ``points`` (N, 3) spread most."""
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    return np.linalg.eigh(xy.T @ xy)[1][:, 1]


def _frame_camera(vis: Any, points: np.ndarray) -> None:
    """Frame ``points`` (N, 3): the camera looks at their middle, broadside to their widest horizontal
    spread (an arm's reach, or the reconstruction and truth side by side), from far enough to see most
    of them (a robust size: rare far excursions do not push the camera away).

    meshcat 0.3.2's orbit controls always look at the world origin, so the scene (with its ground grid
    and axes) is moved to put the middle of the points there, rather than the camera's target moved.
    """
    import meshcat.transformations as tf

    centre = points.mean(axis=0)
    axis = _principal_axis(points)
    side = np.array([-axis[1], axis[0]])
    side = side if side[0] + 1e-3 * side[1] >= 0 else -side
    size = 2.0 * max(float(np.percentile(np.linalg.norm(points - centre, axis=1), 90)), 1e-3)
    vis["chainspace"].set_transform(tf.translation_matrix(-centre))
    vis["/Axes"].set_transform(tf.translation_matrix(-centre))
    vis["/Grid"].set_transform(tf.translation_matrix([0.0, 0.0, -centre[2]]))
    d = 1.2 * size
    # the camera object sits in a Y-up (three.js) node: world (x, y, z) is [x, z, -y] there
    vis["/Cameras/default/rotated/<object>"].set_property("position", [d * side[0], 0.45 * d, -d * side[1]])


# ---------------------------------------------------------------------------------------- entry points
def _with_summary(html: str, fit: Any) -> str:
    """The page with the fit's per-joint status and standard deviations (:meth:`JointFit.summary`) in
    a corner: how sure the fit is, where the animation cannot say it."""
    import html as html_lib

    text = html_lib.escape(fit.summary())
    box = ('<pre id="chainspace-fit-summary" style="position:fixed;left:8px;bottom:8px;margin:0;padding:6px;'
           'max-width:60%;max-height:40%;overflow:auto;background:rgba(255,255,255,0.85);font:11px monospace;'
           f'z-index:10;white-space:pre-wrap">{text}</pre>')
    return html.replace("</body>", box + "</body>", 1) if "</body>" in html else html + box


def write_html(path: str | os.PathLike, rec_or_poses: Any = None, *, chain: Any = None, truth: Any = None,
               fit: Any = None, fps: float | None = None, overwrite: bool = False, camera: Any = None,
               camera_pose: Any = None) -> Path:
    """Write one standalone HTML file animating the motion (see :func:`build_scene` for the inputs).

    The file holds meshcat's JavaScript and the scene; a browser opens it from disk with no server and
    no network. Written atomically; an existing file is replaced only with ``overwrite=True``.
    """
    from ..io.results import check_writable

    check_writable([path], overwrite)
    vis = _offline_visualizer()
    build_scene(vis, rec_or_poses, chain=chain, truth=truth, fit=fit, fps=fps, camera=camera,
                camera_pose=camera_pose)
    html = vis.static_html()
    shown_fit = fit if fit is not None else rec_or_poses
    if hasattr(shown_fit, "summary") and hasattr(shown_fit, "joint_status"):
        html = _with_summary(html, shown_fit)
    with atomic_write(path, "w", overwrite) as f:
        f.write(html)
    return Path(path)


def show(rec_or_poses: Any = None, *, chain: Any = None, truth: Any = None, fit: Any = None, fps: float | None = None,
         open_browser: bool = False, zmq_url: str | None = None, camera: Any = None,
         camera_pose: Any = None) -> Any:
    """Show the motion in a live meshcat viewer (starts a meshcat server); return the Visualizer.

    Prints the viewer's URL; ``open_browser=True`` also opens it. The server lives as long as the
    returned Visualizer (keep the process running to look at it).
    """
    vis = _import_meshcat().Visualizer(zmq_url)
    vis.delete()
    build_scene(vis, rec_or_poses, chain=chain, truth=truth, fit=fit, fps=fps, camera=camera,
                camera_pose=camera_pose)
    if open_browser:
        vis.open()
    return vis
