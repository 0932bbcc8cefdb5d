"""Acclaim skeletons (ASF) and motions (AMC), the format of the CMU motion-capture database.

:func:`from_asf` reads a skeleton as a :class:`~chainspace.chain.KinematicChain` whose points are the
root plus the *end point* of every ASF bone, named after the bone (CMU: ``root`` + 30 bones = 31
points). :func:`load_amc` runs the standard Acclaim forward kinematics on a motion file and returns
the positions of those points, (F, J, 3) in metres, vectorised over frames.

Units and axes
    ASF lengths are inches times the ``:units length`` factor (CMU writes ``length 0.45``), so one
    file unit is ``0.0254 / length`` metres (CMU: 0.05644 m). Angles follow ``:units angle`` (ASF) and
    ``:DEGREES`` / ``:RADIANS`` (AMC). Positions keep the file's own axes: CMU is **Y-up**.
    :mod:`chainspace.io.datasets` converts to chainspace's Z-up world.

Forward kinematics (Acclaim convention)
    Each bone has a rest ``direction`` (unit vector, world axes), a ``length`` and an ``axis``: three
    angles and an order giving the bone's local frame ``C`` relative to the world. A frame of motion
    gives the bone's ``dof`` angles in the listed order, which make a local rotation ``M`` (the first
    listed axis applied first, i.e. scipy's extrinsic Euler sequence). With ``L = C M C^-1``, the global
    rotation is ``G_bone = G_parent L`` and the bone's end is ``end_parent + G_bone (length * direction)``.
    The root follows the ASF ``:root`` ``order`` channels (translation, then Euler angles in their order).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..chain import KinematicChain
from ..errors import DescriptionError, DescriptionNotFoundError, located

__all__ = ["from_asf", "load_amc", "read_asf", "AsfSkeleton", "AsfBone", "INCH"]

INCH = 0.0254  # metres
_ROT_DOFS = ("rx", "ry", "rz")
_ROOT_CHANNELS = ("TX", "TY", "TZ", "RX", "RY", "RZ")
_Items = list[tuple[int, list[str]]]  # (line number, tokens) of one ASF section


@dataclass(frozen=True)
class AsfBone:
    """One ASF bone: rest ``direction`` (unit, file axes), ``length`` in metres, local frame ``C``."""

    name: str
    direction: np.ndarray
    length: float
    C: np.ndarray  # noqa: N815 - the Acclaim symbol
    dof: tuple[str, ...]
    line: int


@dataclass(frozen=True)
class AsfSkeleton:
    """A parsed ASF file (what :func:`load_amc` needs beyond the chain)."""

    path: str
    bones: tuple[AsfBone, ...]
    parent: dict[str, str]
    root_order: tuple[str, ...]
    root_axis: str
    root_position: np.ndarray  # metres
    root_C: np.ndarray  # noqa: N815
    unit_m: float  # metres per ASF length unit
    degrees: bool  # ASF angles (axis) in degrees
    name: str = "asf"


# ---------------------------------------------------------------------------------------------- ASF
def _read_lines(path: str | PathLike, kind: str) -> tuple[str, list[str]]:
    p = Path(path)
    if not p.is_file():
        raise DescriptionNotFoundError(f"{p}: {kind} file not found")
    try:
        text = p.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise DescriptionNotFoundError(f"{p}: cannot read {kind} file: {exc}") from None
    if not text.strip():
        raise DescriptionError(f"{p}: the {kind} file is empty")
    return str(p), text.splitlines()  # splitlines handles CRLF and LF


def _floats(tokens: Sequence[str], n: int | None, src: str, line: int, what: str) -> np.ndarray:
    if n is not None and len(tokens) != n:
        raise DescriptionError(located(f"{what} needs {n} numbers, found {len(tokens)}", src, line))
    try:
        vals = np.array([float(t) for t in tokens])
    except ValueError:
        bad = next(t for t in tokens if not _is_number(t))
        raise DescriptionError(located(f"{what}: {bad!r} is not a number", src, line)) from None
    if not np.isfinite(vals).all():
        raise DescriptionError(located(f"{what}: values must be finite", src, line))
    return vals


def _is_number(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def _euler_matrix(angles: Sequence[float], order: str, degrees: bool, src: str, line: int) -> np.ndarray:
    order = order.lower()
    if len(order) != 3 or set(order) != {"x", "y", "z"}:
        raise DescriptionError(located(f"axis order {order.upper()!r} is not a permutation of XYZ", src, line))
    return Rotation.from_euler(order, angles, degrees=degrees).as_matrix()


def _sections(lines: list[str], src: str) -> dict[str, list[tuple[int, list[str]]]]:
    """Split the file into ``:keyword`` sections of (line number, tokens)."""
    out: dict[str, list[tuple[int, list[str]]]] = {}
    current = None
    for no, raw in enumerate(lines, 1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            continue
        if text.startswith(":"):
            key, *rest = text.split()
            current = key.lower()
            if current in out and current in (":root", ":bonedata", ":hierarchy", ":units"):
                raise DescriptionError(located(f"section {key} appears twice", src, no))
            out[current] = [(no, rest)] if rest else []
            continue
        if current is None:
            raise DescriptionError(located(f"text before the first ':' section: {text[:40]!r}", src, no))
        out[current].append((no, text.split()))
    for need in (":root", ":bonedata"):  # :hierarchy is checked after the bones (truncated files)
        if need not in out:
            raise DescriptionError(located(f"missing {need} section: not an ASF skeleton?", src))
    return out


def _parse_units(items: _Items, src: str) -> tuple[float, bool]:
    length, degrees = 1.0, True
    for no, toks in items:
        key = toks[0].lower()
        if key == "length":
            (length,) = _floats(toks[1:], 1, src, no, "units length")
            if length <= 0:
                raise DescriptionError(located("units length must be positive", src, no))
        elif key == "angle":
            if len(toks) != 2 or toks[1].lower() not in ("deg", "rad"):
                raise DescriptionError(located("units angle must be 'deg' or 'rad'", src, no))
            degrees = toks[1].lower() == "deg"
    return INCH / length, degrees


def _parse_root(
    items: _Items, src: str, unit_m: float, degrees: bool
) -> tuple[tuple[str, ...], str, np.ndarray, np.ndarray]:
    got: dict[str, tuple[int, list[str]]] = {}
    for no, toks in items:
        got[toks[0].lower()] = (no, toks[1:])
    if "order" not in got:
        raise DescriptionError(located(":root has no 'order' line", src, items[0][0] if items else None))
    no, order = got["order"]
    order = tuple(t.upper() for t in order)
    bad = [t for t in order if t not in _ROOT_CHANNELS]
    if bad or len(set(order)) != len(order):
        raise DescriptionError(located(f":root order {' '.join(order)!r} must use distinct {_ROOT_CHANNELS}", src, no))
    axis_no, axis = got.get("axis", (no, ["XYZ"]))
    if len(axis) != 1:
        raise DescriptionError(located(":root axis must be one order such as XYZ", src, axis_no))
    pos = got.get("position", (no, ["0", "0", "0"]))
    ori = got.get("orientation", (no, ["0", "0", "0"]))
    position = _floats(pos[1], 3, src, pos[0], ":root position") * unit_m
    C = _euler_matrix(_floats(ori[1], 3, src, ori[0], ":root orientation"), axis[0], degrees, src, axis_no)
    return order, axis[0].upper(), position, C


def _parse_bone(block: list[tuple[int, list[str]]], start: int, src: str, unit_m: float, degrees: bool) -> AsfBone:
    fields: dict[str, tuple[int, list[str]]] = {}
    for no, toks in block:
        key = toks[0].lower()
        if key.startswith("("):  # continuation of a 'limits' line
            continue
        fields[key] = (no, toks[1:])
    if "name" not in fields or len(fields["name"][1]) != 1:
        raise DescriptionError(located("bone block without a single 'name'", src, start))
    name = fields["name"][1][0]
    for need in ("direction", "length"):
        if need not in fields:
            raise DescriptionError(located(f"bone {name!r} has no '{need}'", src, start))
    no, d = fields["direction"]
    direction = _floats(d, 3, src, no, f"bone {name!r} direction")
    norm = np.linalg.norm(direction)
    no, ln = fields["length"]
    (length,) = _floats(ln, 1, src, no, f"bone {name!r} length")
    if length < 0:
        raise DescriptionError(located(f"bone {name!r} has a negative length", src, no))
    if norm < 1e-9 and length > 0:
        raise DescriptionError(located(f"bone {name!r} has a zero direction", src, fields["direction"][0]))
    if "axis" in fields:
        no, ax = fields["axis"]
        if len(ax) != 4:
            raise DescriptionError(located(f"bone {name!r} axis needs 3 angles and an order (e.g. XYZ)", src, no))
        C = _euler_matrix(_floats(ax[:3], 3, src, no, f"bone {name!r} axis"), ax[3], degrees, src, no)
    else:
        C = np.eye(3)
    dof: tuple[str, ...] = ()
    if "dof" in fields:
        no, dof_toks = fields["dof"]
        dof = tuple(t.lower() for t in dof_toks)
        bad = [t for t in dof if t not in _ROT_DOFS]
        if bad:
            raise DescriptionError(
                located(f"bone {name!r} dof {bad[0]!r} is not supported (only rotations rx ry rz)", src, no)
            )
        if len(set(dof)) != len(dof):
            raise DescriptionError(located(f"bone {name!r} lists a dof twice", src, no))
    return AsfBone(name, direction / max(norm, 1e-300), length * unit_m, C, dof, start)


def _parse_bonedata(items: _Items, src: str, unit_m: float, degrees: bool) -> list[AsfBone]:
    bones: list[AsfBone] = []
    block: list[tuple[int, list[str]]] | None = None
    start = 0
    for no, toks in items:
        key = toks[0].lower()
        if key == "begin":
            if block is not None:
                raise DescriptionError(located("'begin' inside a bone block (missing 'end')", src, no))
            block, start = [], no
        elif key == "end":
            if block is None:
                raise DescriptionError(located("'end' without 'begin'", src, no))
            bones.append(_parse_bone(block, start, src, unit_m, degrees))
            block = None
        elif block is None:
            raise DescriptionError(located(f"{toks[0]!r} outside a begin/end bone block", src, no))
        else:
            block.append((no, toks))
    if block is not None:
        raise DescriptionError(located("bone block not closed by 'end' (truncated file?)", src, start))
    if not bones:
        raise DescriptionError(located(":bonedata defines no bones", src))
    seen: dict[str, int] = {}
    for b in bones:
        if b.name == "root" or b.name in seen:
            raise DescriptionError(located(f"bone name {b.name!r} is used twice", src, b.line))
        seen[b.name] = b.line
    return bones


def _parse_hierarchy(items: _Items, src: str, names: set[str]) -> dict[str, str]:
    parent: dict[str, str] = {}
    for no, toks in items:
        if toks[0].lower() in ("begin", "end"):
            continue
        if len(toks) < 2:
            raise DescriptionError(located(f"hierarchy line names no children of {toks[0]!r}", src, no))
        for n in toks:
            if n not in names:
                raise DescriptionError(located(f"hierarchy names unknown bone {n!r}", src, no))
        for child in toks[1:]:
            if child == "root":
                raise DescriptionError(located("hierarchy gives the root a parent", src, no))
            if child in parent:
                raise DescriptionError(
                    located(f"bone {child!r} has two parents ({parent[child]!r} and {toks[0]!r})", src, no)
                )
            parent[child] = toks[0]
    return parent


def _check_tree(parent: dict[str, str], bones: list[AsfBone], src: str) -> None:
    for b in bones:
        if b.name not in parent:
            raise DescriptionError(located(f"bone {b.name!r} is not attached in :hierarchy", src, b.line))
        seen, n = {b.name}, parent[b.name]
        while n != "root":
            if n in seen:
                raise DescriptionError(located(f"the hierarchy has a cycle through bone {b.name!r}", src, b.line))
            seen.add(n)
            n = parent[n]


def read_asf(path: str | PathLike) -> AsfSkeleton:
    """Parse an ASF file into an :class:`AsfSkeleton` (lengths in metres, file axes)."""
    src, lines = _read_lines(path, "ASF")
    sec = _sections(lines, src)
    unit_m, degrees = _parse_units(sec.get(":units", []), src)
    root_order, root_axis, root_pos, root_C = _parse_root(sec[":root"], src, unit_m, degrees)
    bones = _parse_bonedata(sec[":bonedata"], src, unit_m, degrees)
    names = {b.name for b in bones} | {"root"}
    if ":hierarchy" not in sec:
        raise DescriptionError(located("missing :hierarchy section (truncated file?)", src))
    parent = _parse_hierarchy(sec[":hierarchy"], src, names)
    _check_tree(parent, bones, src)
    name_tok = sec.get(":name", [])
    name = " ".join(name_tok[0][1]) if name_tok else Path(src).stem
    return AsfSkeleton(
        src, tuple(bones), parent, root_order, root_axis, root_pos, root_C, unit_m, degrees,
        name=Path(src).stem if name in ("", "VICON") else name,
    )


def _topological(skel: AsfSkeleton) -> list[AsfBone]:
    """Bones ordered so that every parent comes before its children."""
    depth = {}
    for b in skel.bones:
        d, n = 0, b.name
        while n != "root":
            n, d = skel.parent[n], d + 1
        depth[b.name] = d
    return sorted(skel.bones, key=lambda b: depth[b.name])


def from_asf(path: str | PathLike) -> KinematicChain:
    """Read an Acclaim ASF skeleton as a chain.

    Points: ``"root"`` and the end point of every bone, named after the bone, in file order (CMU:
    31 points, point i = end of ASF bone id i). Bones follow the ASF hierarchy. The rest pose is the
    ASF's own rest pose (``direction * length``) in metres, in the file's axes (CMU: Y-up), with the
    root at the ASF root position. ``chain.metadata["asf"]`` holds the parsed skeleton used by
    :func:`load_amc`; ``metadata["asf_path"]`` the file.
    """
    skel = read_asf(path)
    pos = {"root": skel.root_position}
    for b in _topological(skel):
        pos[b.name] = pos[skel.parent[b.name]] + b.length * b.direction
    joints = ["root"] + [b.name for b in skel.bones]
    bones = [(skel.parent[b.name], b.name) for b in _topological(skel)]
    return KinematicChain(
        joints, bones, np.array([pos[j] for j in joints]),
        name=skel.name, source=skel.path,
        metadata={"kind": "asf", "asf_path": skel.path, "asf": skel, "axes": "file (CMU: Y-up)"},
    )


# ---------------------------------------------------------------------------------------------- AMC
def _skeleton_of(chain_or_asf) -> tuple[AsfSkeleton, KinematicChain]:
    if isinstance(chain_or_asf, KinematicChain):
        skel = chain_or_asf.metadata.get("asf")
        if not isinstance(skel, AsfSkeleton):
            raise DescriptionError(
                f"chain {chain_or_asf.name!r} was not made by from_asf: pass the ASF path to load_amc"
            )
        return skel, chain_or_asf
    if not isinstance(chain_or_asf, (str, PathLike)):
        raise DescriptionError(
            f"load_amc needs a chain made by from_asf or an ASF path, not {type(chain_or_asf).__name__}"
        )
    chain = from_asf(chain_or_asf)
    return chain.metadata["asf"], chain


def _parse_amc(lines: list[str], src: str, skel: AsfSkeleton) -> tuple[np.ndarray, dict[str, np.ndarray], bool]:
    """Read every frame into per-bone arrays: frame numbers (F,), {bone: (F, n_dof)}, degrees."""
    width = {b.name: len(b.dof) for b in skel.bones}
    width["root"] = len(skel.root_order)
    values: dict[str, list[list[float]]] = {n: [] for n, w in width.items() if w}
    frame_nos: list[int] = []
    frame_line: list[int] = []
    degrees = True
    seen: set[str] = set()

    def close_frame() -> None:
        missing = [n for n in values if n not in seen]
        if missing:
            raise DescriptionError(
                located(
                    f"frame {frame_nos[-1]} is truncated: no values for {', '.join(missing[:6])}"
                    f"{', ...' if len(missing) > 6 else ''}",
                    src, frame_line[-1],
                )
            )

    number = re.compile(r"^\d+$")
    for no, raw in enumerate(lines, 1):
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        if text.startswith(":"):
            key = text.split()[0].upper()
            if frame_nos:
                raise DescriptionError(located(f"{key} after the first frame", src, no))
            if key == ":RADIANS":
                degrees = False
            elif key == ":DEGREES":
                degrees = True
            continue
        if number.match(text):
            if frame_nos:
                close_frame()
                if int(text) != frame_nos[-1] + 1:
                    raise DescriptionError(
                        located(f"frame {text} follows frame {frame_nos[-1]}: frames must be consecutive", src, no)
                    )
            frame_nos.append(int(text))
            frame_line.append(no)
            seen = set()
            continue
        name, *toks = text.split()
        if not frame_nos:
            raise DescriptionError(located(f"bone values before the first frame number: {text[:40]!r}", src, no))
        if name not in width:
            raise DescriptionError(located(f"frame {frame_nos[-1]}: unknown bone {name!r}", src, no))
        if name in seen:
            raise DescriptionError(located(f"frame {frame_nos[-1]}: bone {name!r} appears twice", src, no))
        if len(toks) != width[name]:
            raise DescriptionError(
                located(
                    f"frame {frame_nos[-1]}: bone {name!r} has {len(toks)} values, the ASF gives it {width[name]}",
                    src, no,
                )
            )
        seen.add(name)
        if width[name]:
            values[name].append(_floats(toks, None, src, no, f"frame {frame_nos[-1]} bone {name!r}").tolist())
    if not frame_nos:
        raise DescriptionError(located("the AMC file has no frames", src))
    close_frame()  # a file cut short fails here, naming its last frame
    arrays = {n: np.asarray(v, dtype=float).reshape(len(frame_nos), width[n]) for n, v in values.items()}
    return np.asarray(frame_nos), arrays, degrees


def _root_motion(skel: AsfSkeleton, vals: np.ndarray, degrees: bool) -> tuple[np.ndarray, np.ndarray]:
    """Root translation (F, 3) metres and global rotation (F, 3, 3) from the root channels."""
    F = len(vals)
    order = skel.root_order
    t = np.tile(skel.root_position, (F, 1))
    for k, axis in enumerate("XYZ"):
        if f"T{axis}" in order:
            t[:, k] = vals[:, order.index(f"T{axis}")] * skel.unit_m
    rot = [c for c in order if c.startswith("R")]
    if rot:
        M = Rotation.from_euler("".join(c[1].lower() for c in rot), vals[:, [order.index(c) for c in rot]],
                                degrees=degrees).as_matrix()
    else:
        M = np.tile(np.eye(3), (F, 1, 1))
    return t, skel.root_C @ M @ skel.root_C.T


def load_amc(chain_or_asf: KinematicChain | str | PathLike, amc_path: str | PathLike) -> np.ndarray:
    """Joint positions (F, J, 3) in metres of an AMC motion, in the chain's joint order and file axes.

    ``chain_or_asf`` is a chain made by :func:`from_asf` or the ASF path. Frames may start at any
    number (some redistributed CMU files start after frame 1) but must be consecutive. Every
    malformed line raises :class:`~chainspace.errors.DescriptionError` with ``file:line``.
    """
    skel, chain = _skeleton_of(chain_or_asf)
    src, lines = _read_lines(amc_path, "AMC")
    _, vals, degrees = _parse_amc(lines, src, skel)
    F = len(next(iter(vals.values()))) if vals else 0
    if "root" not in vals:
        raise DescriptionError(located("the ASF root has no channels, so the AMC has no root motion", skel.path))
    pos, glob = {}, {}
    pos["root"], glob["root"] = _root_motion(skel, vals["root"], degrees)
    for b in _topological(skel):
        G = glob[skel.parent[b.name]]
        if b.dof:
            M = Rotation.from_euler("".join(d[1] for d in b.dof), vals[b.name], degrees=degrees).as_matrix()
            G = G @ (b.C @ M @ b.C.T)
        glob[b.name] = G
        pos[b.name] = pos[skel.parent[b.name]] + G @ (b.length * b.direction)
    out = np.empty((F, chain.n_joints, 3))
    for j, name in enumerate(chain.joints):
        if name not in pos:
            raise DescriptionError(f"{src}: chain joint {name!r} is not a bone of {skel.path}")
        out[:, j] = pos[name]
    return out
