"""Real motion data for tests, benchmarks and the demo, in chainspace's world: **Z-up, metres**.

Sources (see ``chainspace/data/PROVENANCE.md`` and ``../shared/data/PROVENANCE.md``):

* the CMU Graphics Lab Motion Capture Database (http://mocap.cs.cmu.edu; "The database was created
  with funding from NSF EIA-0196217"), ASF/AMC files. A few are bundled in ``chainspace/data/cmu`` so
  that tests and the demo run without the shared data folder;
* DeepMimic's humanoid clips and the Laikago gait shipped with PyBullet (shared data only).

The shared data folder is ``$CHAINSPACE_DATA`` when set, else ``../shared/data`` beside the repository.
Functions that need it raise :class:`~chainspace.errors.DescriptionNotFoundError` when it is absent.

Axes. CMU and DeepMimic files are Y-up. :func:`to_z_up` turns them into Z-up with the proper rotation
(+90 degrees about x): ``(x, y, z) -> (x, -z, y)``; handedness is kept, so left stays left.

human17 (H36M-style 17 joints) from the CMU 31-point skeleton (point = end of an ASF bone):
pelvis = root, hips = end of l/rhipjoint, knees = end of l/rfemur, ankles = end of l/rtibia,
spine = end of upperback (two thirds of the way from the root to the neck base; the end of lowerback is
one third), thorax = end of thorax (the neck base, where the clavicles start), neck = end of upperneck
(the skull base; thorax-neck-head then has H36M's proportions), head = end of head (top of the head),
shoulders = end of l/rclavicle, elbows = end of l/rhumerus, wrists = end of l/rradius.
Two human17 bones span two CMU bones with a joint between them (pelvis-spine: lowerback + upperback;
thorax-neck: lowerneck + upperneck; :data:`HUMAN17_COMPOSITE_BONES`), so their lengths are not exactly
constant: they vary by under 1 mm over the CMU walks and about 2 mm over the subject-09 runs. Every
other human17 bone is one CMU bone and keeps its length exactly.
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from functools import lru_cache
from importlib import resources
from os import PathLike
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .asf import from_asf, load_amc
from ..chain import KinematicChain
from ..errors import DescriptionError, DescriptionNotFoundError, TrackError

__all__ = [
    "HUMAN17_JOINTS",
    "HUMAN17_BONES",
    "CMU_JOINTS",
    "CMU_TO_HUMAN17",
    "CMU_FPS",
    "HUMAN17_COMPOSITE_BONES",
    "shared_data_dir",
    "bundled_data_dir",
    "to_z_up",
    "human17",
    "cmu_positions",
    "cmu_to_human17",
    "cmu_trials",
    "cmu_walk",
    "cmu09_runs",
    "deepmimic_clip",
    "DEEPMIMIC_CLIPS",
    "laikago_gait",
]

HUMAN17_JOINTS = (
    "pelvis", "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle",
    "spine", "thorax", "neck", "head", "left_shoulder", "left_elbow", "left_wrist",
    "right_shoulder", "right_elbow", "right_wrist",
)
HUMAN17_BONES = (
    ("pelvis", "left_hip"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
    ("pelvis", "right_hip"), ("right_hip", "right_knee"), ("right_knee", "right_ankle"),
    ("pelvis", "spine"), ("spine", "thorax"), ("thorax", "neck"), ("neck", "head"),
    ("thorax", "left_shoulder"), ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
    ("thorax", "right_shoulder"), ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"),
)
# The CMU skeleton's points in ASF bone-id order (point i = end of bone id i; 0 = root).
CMU_JOINTS = (
    "root", "lhipjoint", "lfemur", "ltibia", "lfoot", "ltoes", "rhipjoint", "rfemur", "rtibia", "rfoot",
    "rtoes", "lowerback", "upperback", "thorax", "lowerneck", "upperneck", "head", "lclavicle",
    "lhumerus", "lradius", "lwrist", "lhand", "lfingers", "lthumb", "rclavicle", "rhumerus", "rradius",
    "rwrist", "rhand", "rfingers", "rthumb",
)
CMU_TO_HUMAN17 = {
    "pelvis": "root", "left_hip": "lhipjoint", "left_knee": "lfemur", "left_ankle": "ltibia",
    "right_hip": "rhipjoint", "right_knee": "rfemur", "right_ankle": "rtibia", "spine": "upperback",
    "thorax": "thorax", "neck": "upperneck", "head": "head", "left_shoulder": "lclavicle",
    "left_elbow": "lhumerus", "left_wrist": "lradius", "right_shoulder": "rclavicle",
    "right_elbow": "rhumerus", "right_wrist": "rradius",
}
HUMAN17_COMPOSITE_BONES = (("pelvis", "spine"), ("thorax", "neck"))
CMU_FPS = 120.0  # CMU's capture rate; AMC files do not store it
_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # rows: new x, y, z


# ------------------------------------------------------------------------------------------ places
def shared_data_dir() -> Path | None:
    """The shared real-data folder: ``$CHAINSPACE_DATA``, else ``../shared/data`` beside the repo."""
    env = os.environ.get("CHAINSPACE_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2].parent / "shared" / "data")
    return next((p for p in candidates if p.is_dir()), None)


def bundled_data_dir() -> Path:
    """``chainspace/data``: the small real data shipped inside the package."""
    return Path(str(resources.files("chainspace") / "data"))


def _need_shared(*parts: str) -> Path:
    root = shared_data_dir()
    where = "$CHAINSPACE_DATA or ../shared/data beside the repository"
    if root is None:
        raise DescriptionNotFoundError(f"the shared data folder is absent (looked for {where}); "
                                       f"{'/'.join(parts)} is only there")
    path = root.joinpath(*parts)
    if not path.exists():
        raise DescriptionNotFoundError(f"{path}: not found in the shared data folder")
    return path


def to_z_up(points: np.ndarray) -> np.ndarray:
    """Y-up points (..., 3) to Z-up: ``(x, y, z) -> (x, -z, y)``, a rotation (handedness kept)."""
    return np.asarray(points, dtype=float) @ _Y_TO_Z.T


# ------------------------------------------------------------------------------------------ human17
def human17() -> KinematicChain:
    """The shipped 17-joint human skeleton (``robots/human17.toml``), Z-up metres, with rest pose."""
    from .skeleton_file import from_skeleton_file

    return from_skeleton_file(resources.files("chainspace.robots") / "human17.toml")


def cmu_to_human17(poses31: np.ndarray, chain: KinematicChain | None = None) -> np.ndarray:
    """CMU 31-point poses (F, 31, 3) -> human17 poses (F, 17, 3) (see the module docstring).

    The points are taken in :data:`CMU_JOINTS` order unless ``chain`` (e.g. from :func:`from_asf`)
    gives the order.
    """
    P = np.asarray(poses31, dtype=float)
    names = list(chain.joints) if chain is not None else list(CMU_JOINTS)
    if P.ndim < 2 or P.shape[-2:] != (len(names), 3):
        raise TrackError(f"CMU poses have shape {P.shape}, expected (..., {len(names)}, 3)")
    missing = [n for n in CMU_TO_HUMAN17.values() if n not in names]
    if missing:
        raise TrackError(f"the CMU chain lacks points {', '.join(missing)} needed for human17")
    return P[..., [names.index(CMU_TO_HUMAN17[j]) for j in HUMAN17_JOINTS], :]


# ------------------------------------------------------------------------------------------ CMU
def cmu_positions(asf_path: str | PathLike, amc_path: str | PathLike) -> tuple[KinematicChain, np.ndarray]:
    """The CMU skeleton (31 points) and its motion (F, 31, 3), both Z-up metres.

    The chain's rest pose is the ASF rest pose turned Z-up; ``chain.metadata["asf"]`` still
    describes the file (Y-up), so :func:`chainspace.load_amc` on it returns Y-up positions.
    """
    chain = from_asf(asf_path)
    poses = to_z_up(load_amc(chain, amc_path))
    meta = dict(chain.metadata, axes="z-up (converted from the file's Y-up)")
    chain = KinematicChain(chain.joints, chain.bones, to_z_up(chain.rest_pose),
                           name=chain.name, source=chain.source, metadata=meta)
    return chain, poses


def cmu_trials(subject: int | str) -> list[tuple[Path, Path]]:
    """``(asf, amc)`` paths of a CMU subject's trials in the shared data (empty if absent)."""
    root = shared_data_dir()
    sub = _subject(subject)
    folder = root / "cmu" / sub if root else None
    if folder is None or not (folder / f"{sub}.asf").is_file():
        return []
    return [(folder / f"{sub}.asf", amc) for amc in sorted(folder.glob(f"{sub}_*.amc"))]


def _subject(subject: int | str) -> str:
    try:
        return f"{int(subject):02d}"
    except (TypeError, ValueError):
        raise DescriptionError(f"CMU subject {subject!r} is not a number such as 35") from None


def _cmu_files(subject: int | str, trial: int | str) -> tuple[Path, Path]:
    sub = _subject(subject)
    try:
        name = f"{sub}_{int(trial):02d}"
    except (TypeError, ValueError):
        raise DescriptionError(f"CMU trial {trial!r} is not a number such as 1") from None
    places = []
    if (root := shared_data_dir()) is not None:
        places.append(root / "cmu" / sub)
    places.append(bundled_data_dir() / "cmu")
    for folder in places:
        asf, amc = folder / f"{sub}.asf", folder / f"{name}.amc"
        if asf.is_file() and amc.is_file():
            return asf, amc
    raise DescriptionNotFoundError(
        f"CMU trial {name} not found in {' or '.join(map(str, places))} "
        f"(bundled: {', '.join(sorted(p.stem for p in (bundled_data_dir() / 'cmu').glob('*.amc')))})"
    )


def cmu_walk(subject: int | str, trial: int | str) -> np.ndarray:
    """human17 poses (F, 17, 3), Z-up metres, of CMU trial ``subject_trial`` (120 Hz).

    Reads the shared data when present, else the copies bundled in ``chainspace/data/cmu``
    (35_01, 35_02, 07_01).
    """
    chain, poses = cmu_positions(*_cmu_files(subject, trial))
    return cmu_to_human17(poses, chain)


def cmu09_runs() -> list[np.ndarray]:
    """The 11 CMU subject-09 runs as human17 poses, each (T, 17, 3), Z-up metres, 120 Hz.

    From ``cmu/09/09_run_positions_egno.npz`` (shared data): positions in ASF units, Y-up, point i =
    end of ASF bone id i. Which CMU trial each sequence is was not recorded.
    """
    path = _need_shared("cmu", "09", "09_run_positions_egno.npz")
    try:
        with np.load(path) as data:
            keys = sorted(k for k in data.files if k.startswith("seq_"))
            seqs = [np.asarray(data[k], dtype=float) for k in keys]
    except (OSError, ValueError) as exc:
        raise DescriptionError(f"{path}: cannot read: {exc}") from None
    unit = 0.0254 / 0.45  # CMU ASF length unit in metres
    return [cmu_to_human17(to_z_up(s * unit)) for s in seqs]


# ------------------------------------------------------------------------------------------ DeepMimic
DEEPMIMIC_CLIPS = (
    "backflip", "cartwheel", "crawl", "dance_a", "dance_b", "getup_facedown", "getup_faceup", "jump",
    "kick", "punch", "roll", "run", "spin", "spinkick", "walk",
)
_DEEPMIMIC_SCALE = 0.25  # DeepMimic loads humanoid.urdf with globalScaling=0.25
# Frame layout: duration, root position (3), root quaternion, then per joint a quaternion (w first)
# or one revolute angle, in this order.
_DEEPMIMIC_LAYOUT = (
    ("chest", 4), ("neck", 4), ("right_hip", 4), ("right_knee", 1), ("right_ankle", 4),
    ("right_shoulder", 4), ("right_elbow", 1), ("left_hip", 4), ("left_knee", 1), ("left_ankle", 4),
    ("left_shoulder", 4), ("left_elbow", 1),
)
# URDF link -> human17 name. The model has no separate thorax and neck: its 'neck' joint sits at the
# base of the neck (human17 'thorax') and its head is one rigid link whose centre we track as 'head'.
_DEEPMIMIC_NAMES = {
    "root": "pelvis", "chest": "spine", "neck": "thorax", "right_hip": "right_hip",
    "right_knee": "right_knee", "right_ankle": "right_ankle", "right_shoulder": "right_shoulder",
    "right_elbow": "right_elbow", "right_wrist": "right_wrist", "left_hip": "left_hip",
    "left_knee": "left_knee", "left_ankle": "left_ankle", "left_shoulder": "left_shoulder",
    "left_elbow": "left_elbow", "left_wrist": "left_wrist",
}
_DEEPMIMIC_HEAD = ("neck", np.array([0.0, 0.7, 0.0]))  # head sphere centre in the neck link (URDF units)


@lru_cache(maxsize=4)
def _deepmimic_model(urdf: Path) -> tuple[dict, tuple[str, ...]]:
    """Joint tree of humanoid.urdf: {child link: (parent link, origin xyz, type, axis)}, link order."""
    try:
        # PyBullet's copy ends with a NUL byte, which XML parsers reject.
        root = ET.fromstring(urdf.read_bytes().rstrip(b"\x00\r\n\t "))
        tree, order = {}, ["root"]
        for j in root.iter("joint"):
            parent, child = j.find("parent").get("link"), j.find("child").get("link")
            xyz = np.array([float(v) for v in j.find("origin").get("xyz").split()])
            axis = j.find("axis")
            ax = np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else None
            if j.get("type") != "fixed" or child != "root":
                tree[child] = (parent, xyz, j.get("type"), ax)
                order.append(child)
    except (ET.ParseError, OSError, AttributeError, ValueError) as exc:
        raise DescriptionError(f"{urdf}: not the DeepMimic humanoid URDF: {exc!r}") from None
    if set(order) != set(_DEEPMIMIC_NAMES):
        raise DescriptionError(f"{urdf}: links {sorted(order)} are not the DeepMimic humanoid's")
    return tree, tuple(order)


def deepmimic_clip(name: str) -> tuple[KinematicChain, np.ndarray]:
    """A DeepMimic humanoid clip: (chain, poses (F, 16, 3)) in Z-up metres.

    The clip (``humanoid3d_<name>.txt``) drives PyBullet's ``humanoid/humanoid.urdf`` at DeepMimic's
    scale 0.25. That URDF uses PyBullet's own ``spherical`` joint type, which neither Pinocchio nor
    yourdfpy read, so the forward kinematics of its 12-joint tree (quaternions, w first, and revolute
    knees and elbows about z) is done here with scipy rotations. The 16 points carry human17 names: the
    model's joint centres plus the centre of its head; it has no separate 'neck' point (its neck joint
    sits at the neck base, named 'thorax'). ``chain.metadata["fps"]`` is the clip's frame rate.
    """
    if name not in DEEPMIMIC_CLIPS:
        raise DescriptionError(f"unknown DeepMimic clip {name!r}; choose one of {', '.join(DEEPMIMIC_CLIPS)}")
    clip = _need_shared("deepmimic_pybullet", "motions", f"humanoid3d_{name}.txt")
    urdf = _need_shared("deepmimic_pybullet", "humanoid", "humanoid.urdf")
    frames = _read_frames(clip, 44)
    tree, links = _deepmimic_model(urdf)
    values, k = {}, 8
    for joint, width in _DEEPMIMIC_LAYOUT:
        values[joint] = frames[:, k : k + width]
        k += width
    s = _DEEPMIMIC_SCALE
    pos = {"root": frames[:, 1:4]}
    rot = {"root": Rotation.from_quat(frames[:, 4:8], scalar_first=True)}
    for link in links[1:]:  # URDF order lists parents first
        parent, xyz, kind, axis = tree[link]
        pos[link] = pos[parent] + rot[parent].apply(s * xyz)
        if kind == "spherical":
            rot[link] = rot[parent] * Rotation.from_quat(values[link], scalar_first=True)
        elif kind == "revolute":
            rot[link] = rot[parent] * Rotation.from_rotvec(values[link] * axis)
        else:
            rot[link] = rot[parent]
    head_link, head_xyz = _DEEPMIMIC_HEAD
    points = {_DEEPMIMIC_NAMES[link]: pos[link] for link in links}
    points["head"] = pos[head_link] + rot[head_link].apply(s * head_xyz)
    bones = [(_DEEPMIMIC_NAMES[tree[l][0]], _DEEPMIMIC_NAMES[l]) for l in links[1:]] + [("thorax", "head")]
    joints = [j for j in HUMAN17_JOINTS if j in points]
    poses = to_z_up(np.stack([points[j] for j in joints], axis=1))
    rest = _deepmimic_rest(tree, links, joints)
    chain = KinematicChain(joints, bones, rest, name=f"deepmimic-{name}", source=urdf,
                           metadata={"kind": "deepmimic", "clip": str(clip), "fps": 1.0 / frames[0, 0]})
    return chain, poses


def _deepmimic_rest(tree: dict, links: tuple[str, ...], joints: list[str]) -> np.ndarray:
    """The model's zero pose (standing, arms down), Z-up metres, pelvis at the origin."""
    pos = {"root": np.zeros(3)}
    for link in links[1:]:
        pos[link] = pos[tree[link][0]] + _DEEPMIMIC_SCALE * tree[link][1]
    pts = {_DEEPMIMIC_NAMES[l]: p for l, p in pos.items()}
    pts["head"] = pos[_DEEPMIMIC_HEAD[0]] + _DEEPMIMIC_SCALE * _DEEPMIMIC_HEAD[1]
    return to_z_up(np.array([pts[j] for j in joints]))


def _read_frames(path: Path, width: int) -> np.ndarray:
    """The ``Frames`` of a DeepMimic motion file as an (F, width) array."""
    try:
        data = json.loads(path.read_text())
        frames = np.asarray(data["Frames"], dtype=float)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DescriptionError(f"{path}: not a DeepMimic motion file: {exc}") from None
    if frames.ndim != 2 or frames.shape[1] != width or len(frames) == 0:
        raise DescriptionError(f"{path}: frames have shape {frames.shape}, expected (F, {width})")
    if not np.isfinite(frames).all():
        raise DescriptionError(f"{path}: frame values must be finite")
    return frames


# ------------------------------------------------------------------------------------------ Laikago
# The 12 angles of a frame follow PyBullet's joint indices, i.e. the URDF's joint order.
_LAIKAGO_JOINTS = tuple(
    f"{leg}_{part}" for leg in ("FR", "FL", "RR", "RL")
    for part in ("hip_motor_2_chassis_joint", "upper_leg_2_hip_motor_joint", "lower_leg_2_upper_leg_joint")
)
# The clip stores "motor" angles; the URDF angle is direction * angle + offset (bullet3,
# examples/pybullet/gym/pybullet_envs/deep_mimic/env/testLaikago.py: jointDirections, jointOffsets).
_LAIKAGO_DIRECTION = np.array([-1, 1, 1, 1, 1, 1, -1, 1, 1, 1, 1, 1], dtype=float)
_LAIKAGO_OFFSET = np.tile([0.0, -0.7, 0.7], 4)
# Toe points, as PyBullet's laikago_toes.urdf fixes them to the lower legs (jtoeFR ... jtoeRL).
_LAIKAGO_TOE = (0.0, -0.25, -0.022)


def _inertial_origin(urdf: Path, link: str) -> np.ndarray:
    """The ``<inertial><origin xyz>`` of a URDF link (zero when absent)."""
    try:
        root = ET.fromstring(urdf.read_bytes().rstrip(b"\x00\r\n\t "))
        el = root.find(f"./link[@name='{link}']/inertial/origin")
        return np.zeros(3) if el is None else np.array([float(v) for v in el.get("xyz", "0 0 0").split()])
    except (ET.ParseError, OSError, ValueError) as exc:
        raise DescriptionError(f"{urdf}: cannot read the inertial origin of {link!r}: {exc}") from None


def laikago_gait() -> tuple[KinematicChain, np.ndarray]:
    """The Laikago quadruped's gait clip: (chain, poses (F, 17, 3)), Z-up metres, 16 Hz.

    ``laikago_walk.txt`` gives per frame the base position, the base orientation and 12 leg joint
    "motor" angles for PyBullet's ``laikago/laikago.urdf`` (a Y-up model that the base orientation
    turns into PyBullet's Z-up world). URDF angle = direction * angle + offset, with the directions
    and offsets of bullet3's ``deep_mimic/env/testLaikago.py``. The chain is
    :func:`chainspace.io.urdf.from_urdf` of that URDF plus a toe point per leg (``toeFR`` ... at
    (0, -0.25, -0.022) m in the lower-leg frame, as in PyBullet's ``laikago_toes.urdf``); positions
    are Pinocchio's forward kinematics of the chain's frames, moved by the base pose. PyBullet's base
    pose is that of the chassis' centre of mass (0.03 m and 0.044 m off the chassis frame), which is
    taken into account. The base quaternion is read x, y, z, w (PyBullet's order), not w first as in
    the humanoid clips: read so, the robot stands upright, walks towards its head and its stance toes
    slide least (about 4 mm per frame; 8 mm with the component order of testLaikago.py's kinematic
    mode, and read w first it stands on its head). ``chain.metadata["q"]`` holds the (F, nq)
    configurations in Pinocchio order.
    """
    from .urdf import from_urdf, pinocchio_model, point_positions

    urdf = _need_shared("deepmimic_pybullet", "laikago", "laikago.urdf")
    clip = _need_shared("deepmimic_pybullet", "motions", "laikago_walk.txt")
    frames = _read_frames(clip, 20)
    toes = {f"toe{leg}": (f"{leg}_lower_leg", _LAIKAGO_TOE) for leg in ("FR", "FL", "RR", "RL")}
    chain = from_urdf(urdf, extra_frames=toes, name="laikago")
    model = pinocchio_model(chain)
    q = np.tile(np.asarray(chain.metadata["q_rest"], dtype=float), (len(frames), 1))
    for k, name in enumerate(_LAIKAGO_JOINTS):
        if not model.existJointName(name):
            raise DescriptionError(f"{urdf}: joint {name!r} of the gait clip is not in the URDF")
        jm = model.joints[model.getJointId(name)]
        angle = _LAIKAGO_DIRECTION[k] * frames[:, 8 + k] + _LAIKAGO_OFFSET[k]
        if jm.nq == 2:  # continuous joint: Pinocchio stores (cos, sin)
            q[:, jm.idx_q], q[:, jm.idx_q + 1] = np.cos(angle), np.sin(angle)
        else:
            q[:, jm.idx_q] = angle
    # PyBullet places a body by its base's centre of mass: the chassis frame sits at the clip's
    # position minus the (rotated) inertial offset.
    local = point_positions(chain, q, model=model) - _inertial_origin(urdf, chain.root)
    base = Rotation.from_quat(frames[:, 4:8])  # x, y, z, w
    poses = np.einsum("fij,fkj->fki", base.as_matrix(), local) + frames[:, None, 1:4]
    rest = Rotation.from_quat(frames[0, 4:8]).apply(np.array(chain.rest_pose))  # stands as in frame 0
    meta = dict(chain.metadata, q=q, fps=1.0 / frames[0, 0], clip=str(clip))
    chain = KinematicChain(chain.joints, chain.bones, rest, name="laikago", source=chain.source, metadata=meta)
    return chain, poses
