"""BVH skeletons and motions: read as a chain and joint positions, write joint positions as a motion.

Reading uses bvhio for the HIERARCHY (joints, offsets, channels, End Sites); the MOTION block is
checked line by line here (bvhio does not check value counts and loops forever on a file cut short)
and the forward kinematics run vectorised over frames with scipy rotations.

Points and units
    One point per BVH joint, plus one per non-zero End Site, named ``"<joint>_end"``. A joint whose
    OFFSET is zero always coincides with its parent, so it is merged into the parent's point (the
    point keeps the name closer to the root; ``chain.metadata["merged"]`` lists what was merged).
    Positions are ``scale * file values`` in the file's own axes: the default ``scale=1.0`` reads the
    file as metres; pass ``scale=0.01`` (or ``unit="cm"``) for a file in centimetres, ``0.001`` for
    millimetres; the BVH format itself does not say which unit a file uses.

Conventions (as in bvhio and most BVH tools)
    Rotation channels are intrinsic Euler angles in degrees in the listed order (``Zrotation
    Xrotation Yrotation`` = R_z R_x R_y). Position channels replace the matching OFFSET component.
    A joint's position is its parent's position plus the parent's global rotation applied to the
    joint's offset (or position channels).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..chain import KinematicChain
from ..errors import DescriptionError, DescriptionNotFoundError, OutputExistsError, TrackError, located
from .results import atomic_write

__all__ = ["from_bvh", "load_bvh", "save_bvh"]

_ZERO = 1e-9  # offsets shorter than this (file units) count as zero
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
_ROT = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}


@dataclass
class _Joint:
    name: str
    parent: int  # index into the joint list, -1 for the root
    offset: np.ndarray  # file units
    channels: list[str]
    first: int  # index of its first channel in a motion line
    point: int = -1  # index of the chain point it lands on


@dataclass
class _Skeleton:
    joints: list[_Joint]
    ends: list[tuple[int, np.ndarray]]  # (joint index, End Site offset)
    n_channels: int


# ---------------------------------------------------------------------------------------------- reading
def _read(path: str | PathLike) -> tuple[str, list[str]]:
    p = Path(path)
    if not p.is_file():
        raise DescriptionNotFoundError(f"{p}: BVH file not found")
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DescriptionNotFoundError(f"{p}: cannot read BVH file: {exc}") from None
    if not text.strip():
        raise DescriptionError(f"{p}: the BVH file is empty")
    return str(p), text.splitlines()


def _motion_start(lines: list[str], src: str) -> int:
    """Index of the MOTION line, after checking the structure that keeps bvhio from hanging."""
    first = next((i for i, t in enumerate(lines) if t.strip()), None)
    if first is None or lines[first].strip() != "HIERARCHY":
        raise DescriptionError(located("a BVH file starts with HIERARCHY", src, (first or 0) + 1))
    motion = next((i for i, t in enumerate(lines) if t.strip() == "MOTION"), None)
    if motion is None:
        raise DescriptionError(located("no MOTION section (truncated file?)", src, len(lines)))
    depth = 0
    for i in range(first, motion):
        for tok in lines[i].split():
            depth += (tok == "{") - (tok == "}")
            if depth < 0:
                raise DescriptionError(located("unbalanced '}'", src, i + 1))
    if depth != 0:
        raise DescriptionError(located(f"{depth} unclosed '{{' in HIERARCHY", src, motion + 1))
    header = [(i + 1, t) for i, t in enumerate(lines[motion + 1:], start=motion + 1) if t.strip()][:2]
    if len(header) < 2 or header[0][1].split()[0] != "Frames:" or not header[1][1].strip().startswith("Frame Time:"):
        raise DescriptionError(located("MOTION must be followed by 'Frames: N' and 'Frame Time: T'", src, motion + 1))
    (no_f, frames_line), (no_t, time_line) = header
    try:
        n_frames = int(frames_line.split()[1])
        assert n_frames >= 0 and len(frames_line.split()) == 2
    except (ValueError, IndexError, AssertionError):
        raise DescriptionError(located(f"bad frame count {frames_line.strip()!r}", src, no_f)) from None
    try:
        frame_time = float(time_line.split(":", 1)[1])
        assert np.isfinite(frame_time) and frame_time > 0 and len(time_line.split()) == 3
    except (ValueError, IndexError, AssertionError):
        raise DescriptionError(located(f"bad frame time {time_line.strip()!r}", src, no_t)) from None
    return motion, n_frames, frame_time, no_t


def _hierarchy(path: str, lines: list[str]) -> _Skeleton:
    """Joints, offsets and channels through bvhio, its errors turned into DescriptionErrors."""
    with warnings.catch_warnings():  # PyGLM, under bvhio, warns about its own import path
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio

    _motion_start(lines, path)  # bvhio loops forever on a file that ends inside the hierarchy
    try:
        root = bvhio.readAsBvh(path, loadKeyFrames=False).Root
    except SyntaxError as exc:
        # bvhio's own line numbers are unreliable; its debug info carries the offending text, found
        # here when it is unique in the file.
        info = exc.args[1] if len(exc.args) > 1 and isinstance(exc.args[1], tuple) else ()
        text = info[3].rstrip("\r\n") if len(info) > 3 and isinstance(info[3], str) else None
        hits = [i + 1 for i, t in enumerate(lines) if t == text]
        line = hits[0] if len(hits) == 1 else None
        quote = f" at {text.strip()!r}" if text and line is None else ""
        raise DescriptionError(
            located(f"malformed BVH: {exc.args[0] if exc.args else exc}{quote}", path, line)
        ) from None
    except Exception as exc:  # bvhio raises whatever its parsing hits (IndexError, ValueError, ...)
        raise DescriptionError(located(f"malformed BVH ({type(exc).__name__}: {exc})", path)) from None
    joints: list[_Joint] = []
    ends: list[tuple[int, np.ndarray]] = []
    seen: set[str] = set()
    stack = [(root, -1)]
    count = 0
    while stack:
        bj, parent = stack.pop()
        if bj.Name in seen:
            raise DescriptionError(located(f"joint name {bj.Name!r} appears twice", path, _line_of(lines, bj.Name)))
        seen.add(bj.Name)
        for ch in bj.Channels:
            if ch not in _POS and ch not in _ROT:
                msg = f"joint {bj.Name!r}: unknown channel {ch!r}"
                raise DescriptionError(located(msg, path, _line_of(lines, bj.Name)))
        if len(set(bj.Channels)) != len(bj.Channels):
            msg = f"joint {bj.Name!r}: a channel is listed twice ({' '.join(bj.Channels)})"
            raise DescriptionError(located(msg, path, _line_of(lines, bj.Name)))
        joints.append(_Joint(bj.Name, parent, np.array(bj.Offset, dtype=float), list(bj.Channels), count))
        count += len(bj.Channels)
        k = len(joints) - 1
        if not bj.Children:
            ends.append((k, np.array(bj.EndSite, dtype=float)))
        # Depth-first in file order, as motion lines list channels.
        stack.extend((c, k) for c in reversed(bj.Children))
    return _Skeleton(joints, ends, count)


def _line_of(lines: list[str], name: str) -> int | None:
    pat = re.compile(rf"^\s*(ROOT|JOINT)\s+{re.escape(name)}\s*$")
    hits = [i + 1 for i, t in enumerate(lines) if pat.match(t)]
    return hits[-1] if hits else None


def _chain(skel: _Skeleton, src: str, scale: float, name: str | None) -> KinematicChain:
    names, parents, rest, merged = [], [], [], {}
    pos = np.zeros((len(skel.joints), 3))
    for k, j in enumerate(skel.joints):
        pos[k] = (pos[j.parent] if j.parent >= 0 else 0) + j.offset * scale
        if j.parent >= 0 and np.linalg.norm(j.offset) < _ZERO:
            j.point = skel.joints[j.parent].point
            merged.setdefault(names[j.point], [names[j.point]]).append(j.name)
            continue
        j.point = len(names)
        names.append(j.name)
        parents.append(skel.joints[j.parent].point if j.parent >= 0 else -1)
        rest.append(pos[k])
    for k, off in skel.ends:
        if np.linalg.norm(off) >= _ZERO:
            end = f"{skel.joints[k].name}_end"
            if end in names:
                raise DescriptionError(located(f"End Site name {end!r} clashes with a joint", src))
            names.append(end)
            parents.append(skel.joints[k].point)
            rest.append(pos[k] + off * scale)
    bones = [(names[p], names[i]) for i, p in enumerate(parents) if p >= 0]
    return KinematicChain(
        names, bones, np.array(rest), name=name or Path(src).stem, source=src,
        metadata={"kind": "bvh", "bvh_path": src, "scale": scale, "merged": merged, "axes": "file"},
    )


_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}


def _check_scale(scale: Any, unit: str | None = None) -> float:
    if unit is not None:
        if unit not in _UNITS:
            raise DescriptionError(f"unit {unit!r} must be one of {', '.join(_UNITS)}")
        if scale is not None:
            raise DescriptionError("give either unit or scale, not both")
        return _UNITS[unit]
    if scale is None:
        return 1.0
    try:
        s = float(scale)
    except (TypeError, ValueError):
        raise DescriptionError(f"scale must be a positive number, got {scale!r}") from None
    if not np.isfinite(s) or s <= 0:
        raise DescriptionError(f"scale must be a positive number, got {scale!r}")
    return s


def from_bvh(
    path: str | PathLike, *, scale: float | None = None, unit: str | None = None, name: str | None = None
) -> KinematicChain:
    """The skeleton of a BVH file as a chain; rest pose = the offsets times ``scale`` (metres).

    ``scale`` converts file units to metres: 1.0 (the default) for a file in metres, 0.01 for
    centimetres; or name the file's ``unit`` ("m", "cm", "mm", "in"). Axes are the file's own
    (often Y-up).
    """
    scale = _check_scale(scale, unit)
    src, lines = _read(path)
    return _chain(_hierarchy(src, lines), src, scale, name)


def _motion(lines: list[str], src: str, n_channels: int) -> tuple[np.ndarray, float]:
    """(F, n_channels) motion values and the frame time in seconds, every line checked."""
    _, n_frames, frame_time, no_t = _motion_start(lines, src)
    data = [(i + 1, t) for i, t in enumerate(lines[no_t:], start=no_t) if t.strip()]
    if len(data) < n_frames:
        last = data[-1][0] if data else no_t
        raise DescriptionError(
            located(f"truncated: 'Frames: {n_frames}' but only {len(data)} frame lines", src, last)
        )
    if len(data) > n_frames:
        raise DescriptionError(located(f"more frame lines than 'Frames: {n_frames}'", src, data[n_frames][0]))
    if n_frames == 0:
        raise DescriptionError(located("the motion has no frames", src, no_t - 1))
    for f, (no, text) in enumerate(data):
        n = len(text.split())
        if n != n_channels:
            raise DescriptionError(
                located(f"frame {f}: {n} values, the hierarchy has {n_channels} channels", src, no)
            )
    try:
        values = np.array(" ".join(t for _, t in data).split(), dtype=float).reshape(n_frames, n_channels)
    except ValueError:
        for f, (no, text) in enumerate(data):
            for tok in text.split():
                try:
                    float(tok)
                except ValueError:
                    raise DescriptionError(located(f"frame {f}: {tok!r} is not a number", src, no)) from None
        raise
    if not np.isfinite(values).all():
        f = int(np.flatnonzero(~np.isfinite(values).all(axis=1))[0])
        raise DescriptionError(located(f"frame {f}: values must be finite", src, data[f][0]))
    return values, frame_time


def _forward(skel: _Skeleton, values: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Global positions (F, n, 3) (scaled) and rotations (F, n, 3, 3) of every BVH joint."""
    F = len(values)
    n = len(skel.joints)
    pos = np.zeros((F, n, 3))
    rot = np.zeros((F, n, 3, 3))
    for k, j in enumerate(skel.joints):
        t = np.tile(j.offset, (F, 1))
        order, cols = "", []
        for c, ch in enumerate(j.channels):
            if ch in _POS:
                t[:, _POS[ch]] = values[:, j.first + c]
            else:
                order += _ROT[ch]
                cols.append(j.first + c)
        L = Rotation.from_euler(order, values[:, cols], degrees=True).as_matrix() if order else np.eye(3)
        if j.parent < 0:
            pos[:, k], rot[:, k] = t * scale, np.broadcast_to(L, (F, 3, 3))
        else:
            G = rot[:, j.parent]
            pos[:, k] = pos[:, j.parent] + np.einsum("fij,fj->fi", G, t * scale)
            rot[:, k] = G @ L
    return pos, rot


def load_bvh(
    path: str | PathLike, *, scale: float | None = None, unit: str | None = None, name: str | None = None
) -> tuple[KinematicChain, np.ndarray, float]:
    """Read a BVH motion: ``(chain, poses (F, J, 3) in metres, fps)``; units as in :func:`from_bvh`."""
    scale = _check_scale(scale, unit)
    src, lines = _read(path)
    skel = _hierarchy(src, lines)
    chain = _chain(skel, src, scale, name)
    values, frame_time = _motion(lines, src, skel.n_channels)
    pos, rot = _forward(skel, values, scale)
    out = np.empty((len(values), chain.n_joints, 3))
    for k, j in enumerate(skel.joints):
        out[:, j.point] = pos[:, k]  # merged joints coincide with their point
    ends = [(k, off) for k, off in skel.ends if np.linalg.norm(off) >= _ZERO]
    for e, (k, off) in enumerate(ends):
        out[:, chain.n_joints - len(ends) + e] = pos[:, k] + rot[:, k] @ (off * scale)
    return chain, out, 1.0 / frame_time


# ---------------------------------------------------------------------------------------------- writing
def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F, 3, 3) shortest-arc rotations taking direction ``a`` (3,) onto directions ``b`` (F, 3)."""
    a = a / np.linalg.norm(a)
    nb = np.linalg.norm(b, axis=-1, keepdims=True)
    b = np.where(nb > 0, b / np.where(nb > 0, nb, 1), a)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis, axis=-1), b @ a
    rotvec = axis / np.where(s > 0, s, 1)[:, None] * np.arctan2(s, c)[:, None]
    flip = (s < 1e-12) & (c < 0)  # opposite directions: half a turn about any perpendicular axis
    if flip.any():
        perp = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 1.0, 0.0])
        rotvec[flip] = perp / np.linalg.norm(perp) * np.pi
    return Rotation.from_rotvec(rotvec).as_matrix()


def _fmt(x: np.ndarray) -> str:
    return " ".join(f"{v:.9g}" for v in np.asarray(x).ravel())


def save_bvh(
    path: str | PathLike,
    chain: KinematicChain,
    poses: Any,
    fps: float,
    overwrite: bool = False,
    *,
    scale: float | None = None,
    unit: str | None = None,
) -> Path:
    """Write joint positions (F, J, 3) in metres as a BVH motion; file values = positions / ``scale``
    (default 1.0: the file is in metres; or give the file's ``unit``, e.g. "cm").

    Every chain joint becomes a BVH joint (the root with position channels); offsets are the mean
    bone vectors' lengths along the rest pose's directions (the first frame's when the chain has no
    rest pose): BVH bones cannot change length, so a motion whose bone lengths vary is reproduced up
    to that variation. Each joint's rotation is the shortest-arc *swing* that turns its rest bone onto
    the posed bone; a joint with several children gets one zero-offset helper joint
    ``"<joint>__<child>"`` per further child, which :func:`load_bvh` merges back into the joint. The
    twist of a bone about its own axis cannot be recovered from positions and is written as zero
    swing-only rotations. Leaves get a zero End Site. Axes are written as given (chainspace: Z-up).
    """
    scale = _check_scale(scale, unit)
    X = np.asarray(poses, dtype=float)
    if X.ndim != 3 or X.shape[1:] != (chain.n_joints, 3) or len(X) == 0:
        raise TrackError(f"poses have shape {X.shape}, expected (F>0, {chain.n_joints}, 3) for {chain.name}")
    if not np.isfinite(X).all():
        raise TrackError("poses must be finite to be written as BVH (fill missing points first)")
    try:
        fps = float(fps)
        assert np.isfinite(fps) and fps > 0
    except (TypeError, ValueError, AssertionError):
        raise TrackError(f"fps must be a positive number, got {fps!r}") from None
    p = Path(path)
    if p.exists() and not overwrite:
        raise OutputExistsError(f"{p}: exists; pass overwrite=True to replace it")
    text = _bvh_text(chain, X / scale, fps)
    with atomic_write(p, "w", overwrite) as fh:
        fh.write(text)
    return p


def _bvh_text(chain: KinematicChain, X: np.ndarray, fps: float) -> str:
    """The BVH file for poses X (F, J, 3) in file units."""
    F = len(X)
    idx = chain.joint_index
    children: dict[str, list[str]] = {j: [] for j in chain.joints}
    for a, b in chain.bones:
        children[a].append(b)
    B = X[:, [idx(b) for _, b in chain.bones]] - X[:, [idx(a) for a, _ in chain.bones]]
    length = np.linalg.norm(B, axis=-1).mean(axis=0)
    ref = chain.rest_pose if chain.rest_pose is not None else X[0]
    offsets = {}
    for k, (a, b) in enumerate(chain.bones):
        d = ref[idx(b)] - ref[idx(a)]
        if np.linalg.norm(d) < 1e-12:
            d = B[0, k]
        if np.linalg.norm(d) < 1e-12 or length[k] < 1e-12:
            raise TrackError(f"bone ({a!r}, {b!r}) has zero length: BVH cannot represent it")
        offsets[b] = d / np.linalg.norm(d) * length[k]
    header: list[str] = []
    channels: list[np.ndarray] = []  # per BVH joint, (F, n) values, in file order

    def joint(name: str, kind: str, offset: np.ndarray, G_parent: np.ndarray, at: str, target: str | None,
              rest_dir: np.ndarray | None, depth: int, kids: list[tuple[str, str | None]]) -> None:
        """Write one BVH joint, located at chain joint ``at``, aiming ``rest_dir`` at joint ``target``."""
        pad = "  " * depth
        header.append(f"{pad}{kind} {name}")
        header.append(f"{pad}{{")
        header.append(f"{pad}  OFFSET {_fmt(offset)}")
        if target is not None:
            local = np.einsum("fji,fj->fi", G_parent, X[:, idx(target)] - X[:, idx(at)])  # G_parent^T (x_c - x_p)
            L = _swing(rest_dir, local)
        else:
            L = np.broadcast_to(np.eye(3), (F, 3, 3))
        G = G_parent @ L
        ang = Rotation.from_matrix(L).as_euler("ZXY", degrees=True)
        if kind == "ROOT":
            header.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
            channels.append(np.hstack([X[:, idx(at)], ang]))
        else:
            header.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
            channels.append(ang)
        if not kids:
            header.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 0 0", f"{pad}  }}"])
        for child, helper_target in kids:
            emit(child, G, depth + 1, helper_target)
        header.append(f"{pad}}}")

    def emit(name: str, G_parent: np.ndarray, depth: int, helper_target: str | None = None) -> None:
        if helper_target is not None:  # zero-offset helper at its parent, aiming at one further child
            at = name[: -len(helper_target) - 2]
            joint(name, "JOINT", np.zeros(3), G_parent, at, helper_target, offsets[helper_target], depth,
                  [(helper_target, None)])
            return
        kids = children[name]
        first = kids[0] if kids else None
        plan = [(k, None) for k in kids[:1]] + [(f"{name}__{k}", k) for k in kids[1:]]
        kind = "ROOT" if name == chain.root else "JOINT"
        offset = np.zeros(3) if kind == "ROOT" else offsets[name]
        joint(name, kind, offset, G_parent, name, first, offsets[first] if first else None, depth, plan)

    for a in chain.joints:
        for b in children[a][1:]:
            if f"{a}__{b}" in children:
                raise TrackError(f"helper joint name {a}__{b} clashes with a joint of {chain.name}")
    emit(chain.root, np.broadcast_to(np.eye(3), (F, 3, 3)), 0)
    motion = np.hstack(channels)
    body = "\n".join(_fmt(row) for row in motion)
    return "HIERARCHY\n" + "\n".join(header) + f"\nMOTION\nFrames: {F}\nFrame Time: {1.0 / fps!r}\n" + body + "\n"
