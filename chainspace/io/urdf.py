"""Kinematic chains from URDF robot descriptions.

The points of the chain are URDF link-frame origins, from the base outwards, each named after its
link so that Pinocchio finds it as a frame (``model.getFrameId(name)``). Links whose origins coincide
in every configuration become one point, named after the link closest to the base: a link hung from
its parent by a revolute, continuous or fixed joint with zero origin translation (a spherical wrist,
a zero-offset flange), or siblings hung from one link at the same offset. Extra frames (a tool tip)
are tracked points fixed to a link at an offset given in that link's frame.

The file is read twice, once by ``lxml`` (well-formedness and the structure of the tree, with the
line of each element for error messages, because yourdfpy only logs what it cannot parse) and once by
yourdfpy (joint origins, types, limits); positions come from Pinocchio's forward kinematics, so the
chain agrees with a Pinocchio model built from the same file. Meshes are never loaded.

Units: metres and radians, positions in the frame of the URDF's root link.
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import logging
import os
import re
import sys
import tempfile
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..chain import KinematicChain
from ..errors import DescriptionError, DescriptionNotFoundError, located

__all__ = ["build_model", "from_urdf", "pinocchio_model", "point_positions", "resolve_mesh", "visual_urdf"]

# Joints that keep the child's origin at a fixed offset from the parent's origin.
_RIGID_ORIGIN = {"fixed", "revolute", "continuous"}
_TYPES = {"fixed", "revolute", "continuous", "prismatic", "floating", "planar"}
_LIMITED = {"revolute", "prismatic"}
_VARIABLE_BONE_TOL = 1e-7  # metres; a bone whose length changes more than this is reported


def from_urdf(
    path: str | Path,
    *,
    links: Sequence[str] | None = None,
    extra_frames: Mapping[str, tuple[str, Sequence[float]]] | None = None,
    q: Any = None,
    merge_tolerance: float = 1e-6,
    name: str | None = None,
) -> KinematicChain:
    """Read a URDF file as a :class:`~chainspace.KinematicChain` of link-frame origins.

    Parameters
    ----------
    path
        The URDF file. Mesh files it names need not exist.
    links
        Keep only these points (link or extra-frame names), in this order; each hangs from its
        nearest kept ancestor (:meth:`KinematicChain.subset`). A link merged into another point may
        be named instead of that point; the point then takes the given name. Extra frames not
        listed are kept, at the end.
    extra_frames
        ``{name: (parent_link, (x, y, z))}``: tracked points fixed to ``parent_link``, offset in that
        link's frame, metres (a tool tip).
    q
        The rest configuration: ``{joint_name: value}`` for one-degree-of-freedom joints (radians or
        metres; others stay at zero clipped into their limits), or an array in the order of
        Pinocchio's model of this file, of length ``nq`` or ``nv``. Default: zero clipped into the
        joint limits.
    merge_tolerance
        Joint origin translations (metres) shorter than this count as zero when merging links.
    name
        The chain's name; default: the URDF robot name.

    Returns
    -------
    KinematicChain
        Rest pose (J, 3) in metres in the URDF root-link frame at configuration ``q``. Its
        ``metadata``: ``kind`` ("urdf"), ``urdf_path``, ``robot_name``, ``q_rest`` (nq,) in
        Pinocchio order, ``joint_names`` (Pinocchio's joints, ``universe`` excluded), ``merged``
        ``{point: [links]}`` for points standing for several links, ``extra_frames``
        ``{name: (parent_link, [x, y, z])}``, ``prismatic`` (prismatic joint names: bones across them
        change length) and ``variable_bones`` (bones whose length is not constant over random
        configurations: across prismatic joints, or spanning a moving joint after ``links``).

    Raises
    ------
    DescriptionNotFoundError
        The file does not exist.
    DescriptionError
        Malformed XML, a joint naming an unknown link, a cycle, more than one root, inverted joint
        limits, an unknown name in ``links`` or ``extra_frames``, an unusable ``q``.
    """
    path = Path(path)
    if not path.is_file():
        raise DescriptionNotFoundError(f"URDF file not found: {path}")
    if not (isinstance(merge_tolerance, (int, float)) and merge_tolerance >= 0):
        raise DescriptionError(f"merge_tolerance must be a number >= 0 (metres), not {merge_tolerance!r}")
    tree = _UrdfTree(path)
    urdf = tree.load_yourdfpy()
    model = _build_model(path)
    if model.nv == 0:
        raise tree.error(
            f"the robot {urdf.robot.name!r} has no movable joint (every joint is fixed): there are no joint "
            "angles to fit; a URDF for chainspace needs at least one revolute, continuous or prismatic joint")
    extras = _check_extra_frames(tree, model, extra_frames, merge_tolerance)
    q_rest = _rest_configuration(tree, model, q)
    groups = _merge_groups(tree, urdf, merge_tolerance)
    rep = {link: members[0] for members in groups for link in members}
    reps = [g[0] for g in groups]

    bones = [(rep[tree.parent_link[r]], r) for r in reps if r in tree.parent_link]
    bones += [(rep[parent], n) for n, (parent, _) in extras.items()]
    points = reps + list(extras)
    metadata = {
        "kind": "urdf",
        "urdf_path": str(path.resolve()),
        "robot_name": urdf.robot.name,
        "q_rest": q_rest,
        "joint_names": list(model.names[1:]),
        "extra_frames": {n: (p, [float(v) for v in xyz]) for n, (p, xyz) in extras.items()},
        "prismatic": [j.name for j in urdf.robot.joints if j.type == "prismatic"],
    }
    chain = KinematicChain(
        points, bones, None, name=name or urdf.robot.name, source=path, metadata=metadata
    )
    if links is not None:
        if isinstance(links, str) or not isinstance(links, Sequence):
            raise tree.error(f"links must be a list of link names, not {links!r}")
        chain = _select(chain, tree, rep, list(links), extras)
    if chain.n_joints < 2:
        kept = ", ".join(map(repr, chain.joints)) or "none"
        raise tree.error(
            f"nothing to track: {chain.n_joints} point left ({kept}) after merging links whose origins "
            "coincide" + (" and keeping `links`" if links is not None else "")
            + "; a chain needs at least 2 points (track more links, or add extra_frames)")
    group = {g[0]: g for g in groups}
    chain.metadata["merged"] = {
        p: group[rep[p]] for p in chain.joints if p in rep and len(group[rep[p]]) > 1
    }
    model = _with_extra_frames(model, chain.metadata["extra_frames"], source=path)
    chain = chain.with_rest_pose(point_positions(chain, q_rest, model=model))
    chain.metadata["variable_bones"] = _variable_bones(chain, model, q_rest)
    return chain


# ---------------------------------------------------------------------------- reading the file
class _UrdfTree:
    """The link tree of a URDF file, checked, with the line of every link and joint element."""

    def __init__(self, path: Path) -> None:
        from lxml import etree

        self.path = path
        try:
            root = etree.parse(str(path), etree.XMLParser(remove_comments=True, resolve_entities=False)).getroot()
        except etree.XMLSyntaxError as exc:
            line = exc.lineno if exc.lineno else None
            raise DescriptionError(located(f"malformed XML: {exc.msg}", path, line)) from None
        except OSError as exc:
            raise DescriptionError(located(f"cannot read the file: {exc}", path)) from None
        self._root = root
        if root.tag != "robot":
            raise self.error(f"the root element is <{root.tag}>, not <robot>: not a URDF file", root)
        self.link_line: dict[str, int] = {}
        self.joint_line: dict[str, int] = {}
        self.links: list[str] = []
        for el in root.findall("link"):
            n = self._name(el, "link")
            if n in self.link_line:
                raise self.error(f"link {n!r} is defined twice (first at line {self.link_line[n]})", el)
            self.link_line[n] = el.sourceline
            self.links.append(n)
        if not self.links:
            raise self.error("the robot has no <link>", root)
        self.parent_link: dict[str, str] = {}
        self.joint_of_child: dict[str, str] = {}
        self.children: dict[str, list[tuple[str, str]]] = {n: [] for n in self.links}
        for el in root.findall("joint"):
            self._read_joint(el)
        self._check_tree(root)

    def error(self, message: str, element: Any = None, line: int | None = None) -> DescriptionError:
        if line is None and element is not None:
            line = element.sourceline
        return DescriptionError(located(message, self.path, line))

    def _name(self, el: Any, kind: str) -> str:
        n = el.get("name")
        if not n or not n.strip():
            raise self.error(f"a <{kind}> has no name", el)
        return n

    def _read_joint(self, el: Any) -> None:
        n = self._name(el, "joint")
        if n in self.joint_line:
            raise self.error(f"joint {n!r} is defined twice (first at line {self.joint_line[n]})", el)
        self.joint_line[n] = el.sourceline
        kind = el.get("type")
        if kind not in _TYPES:
            raise self.error(f"joint {n!r} has type {kind!r}; URDF types are {', '.join(sorted(_TYPES))}", el)
        ends = {}
        for tag in ("parent", "child"):
            sub = el.find(tag)
            link = None if sub is None else sub.get("link")
            if not link:
                raise self.error(f"joint {n!r} has no <{tag} link=...>", el)
            if link not in self.link_line:
                raise self.error(f"joint {n!r} names unknown {tag} link {link!r}{_hint(link, self.links)}", el)
            ends[tag] = link
        parent, child = ends["parent"], ends["child"]
        if parent == child:
            raise self.error(f"joint {n!r} joins link {child!r} to itself", el)
        if child in self.parent_link:
            raise self.error(
                f"link {child!r} is the child of two joints ({self.joint_of_child[child]!r} and {n!r}): "
                "URDF describes a tree, so a link has one parent joint",
                el,
            )
        self.parent_link[child] = parent
        self.joint_of_child[child] = n
        self.children[parent].append((n, child))
        if kind in _LIMITED:
            self._check_limit(el, n)

    def _check_limit(self, el: Any, joint: str) -> None:
        lim = el.find("limit")
        if lim is None:
            raise self.error(f"{el.get('type')} joint {joint!r} has no <limit>", el)
        try:
            lo, hi = (float(lim.get(k, "0")) for k in ("lower", "upper"))
        except ValueError:
            raise self.error(f"joint {joint!r} has a non-numeric limit", lim) from None
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise self.error(f"joint {joint!r} has a non-finite limit ({lo}, {hi})", lim)
        if lo > hi:
            raise self.error(f"joint {joint!r} has inverted limits: lower {lo} > upper {hi}", lim)

    def _check_tree(self, root: Any) -> None:
        roots = [n for n in self.links if n not in self.parent_link]
        if not roots:
            some = ", ".join(f"{self.joint_of_child[n]!r} (line {self.joint_line[self.joint_of_child[n]]})"
                             for n in self.links[:4])
            raise self.error(f"the joints form a cycle: every link has a parent joint (joints {some}...)", root)
        if len(roots) > 1:
            shown = ", ".join(f"{r!r} (line {self.link_line[r]})" for r in roots[:6])
            raise self.error(
                f"the robot is disconnected: {len(roots)} links have no parent joint ({shown}); "
                "a URDF has one root link",
                root,
            )
        self.root = roots[0]
        order = self.dfs()
        if len(order) < len(self.links):
            lost = [n for n in self.links if n not in set(order)]
            first = self.joint_of_child[lost[0]]
            raise self.error(
                f"the joints form a cycle through links {', '.join(map(repr, lost[:6]))} "
                f"(joint {first!r})",
                line=self.joint_line[first],
            )

    def dfs(self) -> list[str]:
        """Links from the root outwards, depth first, children in file order."""
        order, stack = [], [self.root]
        while stack:
            link = stack.pop()
            order.append(link)
            stack.extend(c for _, c in reversed(self.children[link]))
        return order

    def load_yourdfpy(self) -> Any:
        import yourdfpy

        log = logging.getLogger("yourdfpy")
        level = log.level
        log.setLevel(logging.CRITICAL)  # it logs what it cannot parse; lxml has vetted the XML already
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")  # trimesh warns about NaN angles; they are caught later
            try:
                urdf = yourdfpy.URDF.load(
                    str(self.path),
                    build_scene_graph=False,
                    build_collision_scene_graph=False,
                    load_meshes=False,
                    load_collision_meshes=False,
                )
            except Exception as exc:  # yourdfpy raises bare ValueError/TypeError on bad attributes
                raise self._attribute_error(exc) from None
            finally:
                log.setLevel(level)
        self._check_geometry(urdf)
        return urdf

    def _attribute_error(self, exc: Exception) -> DescriptionError:
        """Locate the attribute value a yourdfpy error quotes (``could not convert '0.1x'``)."""
        quoted = re.findall(r"'([^']*)'", str(exc))
        for el in self._root.iter():
            for key, value in el.attrib.items():
                if any(q and q in value for q in quoted):
                    owner = next((a for a in el.iterancestors() if a.tag in ("link", "joint")), el)
                    what = f"<{owner.tag} name={owner.get('name')!r}>" if owner is not el else f"<{el.tag}>"
                    return self.error(f"bad value {key}={value!r} in <{el.tag}> of {what}", el)
        return self.error(f"yourdfpy cannot read the URDF: {type(exc).__name__}: {exc}")

    def _check_geometry(self, urdf: Any) -> None:
        """Joint origins and axes must be finite, moving axes non-zero."""
        for j in urdf.robot.joints:
            line = self.joint_line.get(j.name)
            if j.origin is not None and not np.isfinite(j.origin).all():
                raise self.error(f"joint {j.name!r} has a non-finite <origin>", line=line)
            if j.type in ("revolute", "continuous", "prismatic") and j.axis is not None:
                if not np.isfinite(j.axis).all() or np.linalg.norm(j.axis) == 0:
                    raise self.error(f"joint {j.name!r} has axis {[float(v) for v in j.axis]}: not a direction", line=line)


def _hint(name: str, names: Sequence[str]) -> str:
    close = difflib.get_close_matches(str(name), list(names), n=3)
    return f" (did you mean {', '.join(map(repr, close))}?)" if close else ""


def build_model(path: str | Path) -> Any:
    """Pinocchio's model of a URDF file, as every part of chainspace builds it: mimic joints (``<mimic>``)
    driven by their leader (``buildModelFromUrdf(path, mimic=True)``, Pinocchio >= 3.4), so that they
    are no degree of freedom of their own. With an older Pinocchio a URDF with mimic joints is refused
    (DescriptionError), since its model would fit them as free joints."""
    return _build_model(Path(path))


def _has_mimic(path: Path) -> bool:
    try:
        return "<mimic" in path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False


def _build_model(path: Path) -> Any:
    import pinocchio as pin

    with _captured_stderr() as said:
        try:
            try:
                return pin.buildModelFromUrdf(str(path), mimic=True)
            except TypeError:  # Pinocchio < 3.4: no mimic joints
                pass
            if _has_mimic(path):
                raise DescriptionError(located(
                    f"the URDF has mimic joints, which need Pinocchio >= 3.4 (installed: {pin.__version__}); "
                    "an older model would fit each mimic joint as a free joint", path))
            return pin.buildModelFromUrdf(str(path))
        except DescriptionError:
            raise
        except Exception as exc:  # Pinocchio's C++ parser raises RuntimeError/ValueError
            error = exc
    # urdfdom prints what it could not parse (the element) to the C stderr, not into the exception
    detail = [ln.strip() for ln in said() if ln.strip().startswith("Error:")]
    why = "; ".join(ln.removeprefix("Error:").strip() for ln in detail[:3]) or str(error)
    raise DescriptionError(located(f"Pinocchio cannot build a model: {why}", path))


@contextlib.contextmanager
def _captured_stderr() -> Iterator[Any]:
    """Capture what C++ code writes to file descriptor 2; yields a function returning its lines."""
    lines: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no usable stderr: nothing to capture
        yield lambda: lines
        return
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        sys.stderr.flush()
        os.dup2(tmp.fileno(), 2)
        try:
            yield lambda: lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(tmp.read().decode("utf-8", "replace").splitlines())


# ---------------------------------------------------------------------------- points
def _merge_groups(tree: _UrdfTree, urdf: Any, tol: float) -> list[list[str]]:
    """Links whose origins coincide in every configuration, each group listed base-first."""
    joints = urdf.joint_map
    root_of = {n: n for n in tree.links}

    def find(n: str) -> str:
        while root_of[n] != n:
            root_of[n] = root_of[root_of[n]]
            n = root_of[n]
        return n

    def offset(joint_name: str) -> np.ndarray | None:
        j = joints[joint_name]
        if j.type not in _RIGID_ORIGIN:
            return None
        return np.zeros(3) if j.origin is None else np.asarray(j.origin)[:3, 3]

    for parent, kids in tree.children.items():
        offsets = [(c, offset(jn)) for jn, c in kids]
        rigid = [(c, o) for c, o in offsets if o is not None]
        for c, o in rigid:
            if np.linalg.norm(o) <= tol:  # child origin on the parent origin
                root_of[find(c)] = find(parent)
        for k, (c1, o1) in enumerate(rigid):  # siblings at one offset
            for c2, o2 in rigid[k + 1 :]:
                if np.linalg.norm(o1 - o2) <= tol:
                    root_of[find(c2)] = find(c1)
    groups: dict[str, list[str]] = {}
    for link in tree.dfs():
        groups.setdefault(find(link), []).append(link)
    # The point is named after the member closest to the base (first in depth-first order among
    # the shallowest).
    depth = {tree.root: 0}
    for link in tree.dfs()[1:]:
        depth[link] = depth[tree.parent_link[link]] + 1
    out = []
    for members in groups.values():
        first = min(members, key=lambda n: depth[n])
        out.append([first] + [m for m in members if m != first])
    order = {n: i for i, n in enumerate(tree.dfs())}
    return sorted(out, key=lambda g: order[g[0]])


def _check_extra_frames(
    tree: _UrdfTree, model: Any, extra_frames: Any, tol: float
) -> dict[str, tuple[str, np.ndarray]]:
    if extra_frames is None:
        return {}
    if not isinstance(extra_frames, Mapping):
        raise tree.error("extra_frames must be a mapping {name: (parent_link, (x, y, z))}")
    out = {}
    for n, spec in extra_frames.items():
        if not isinstance(n, str) or not n.strip():
            raise tree.error(f"extra frame name {n!r} is not a non-empty string")
        try:
            parent, xyz = spec
            xyz = np.asarray(xyz, dtype=float)
        except (TypeError, ValueError):
            raise tree.error(f"extra frame {n!r}: expected (parent_link, (x, y, z)), got {spec!r}") from None
        if parent not in tree.link_line:
            raise tree.error(f"extra frame {n!r} names unknown parent link {parent!r}{_hint(parent, tree.links)}")
        if xyz.shape != (3,) or not np.isfinite(xyz).all():
            raise tree.error(f"extra frame {n!r}: offset {spec[1]!r} is not three finite numbers (metres)")
        if np.linalg.norm(xyz) <= tol:
            raise tree.error(f"extra frame {n!r} is at the origin of link {parent!r}: track the link itself")
        if n in tree.link_line or model.existFrame(n):
            raise tree.error(f"extra frame {n!r} has the name of a link, joint or frame of the URDF")
        out[n] = (parent, xyz)
    return out


def _select(
    chain: KinematicChain, tree: _UrdfTree, rep: dict[str, str], names: list[str], extras: dict
) -> KinematicChain:
    """Keep ``names`` (links, merged links or extra frames), then any extra frames not named."""
    if any(not isinstance(n, str) for n in names):
        raise tree.error(f"links must be names (strings), got {names!r}")
    known = list(tree.links) + list(extras)
    points, rename = [], {}
    for n in names:
        if n not in rep and n not in extras:
            raise tree.error(f"unknown link {n!r} in links={_hint(n, known)}")
        p = rep.get(n, n)
        if p in rename:
            raise tree.error(f"links= {rename[p]!r} and {n!r} are one point (merged links); name one of them")
        rename[p] = n
        points.append(p)
    points += [e for e in extras if e not in rename]
    sub = chain.subset(points)
    if all(p == n for p, n in rename.items()):
        return sub
    # A merged link named by the user names the point; it is a frame of the same position.
    new = lambda p: rename.get(p, p)  # noqa: E731
    return KinematicChain(
        [new(p) for p in sub.joints],
        [(new(a), new(b)) for a, b in sub.bones],
        None,
        name=sub.name,
        source=sub.source,
        metadata=sub.metadata,
    )


# ---------------------------------------------------------------------------- configurations
def _rest_configuration(tree: _UrdfTree, model: Any, q: Any) -> np.ndarray:
    """The rest configuration (nq,) in Pinocchio order: zero clipped into limits, or the user's."""
    import pinocchio as pin

    q0 = pin.neutral(model)
    one = [j for j in range(1, model.njoints) if model.joints[j].nq == 1]
    idx = [model.joints[j].idx_q for j in one]
    q0[idx] = np.clip(q0[idx], model.lowerPositionLimit[idx], model.upperPositionLimit[idx])
    if q is None:
        return q0
    if isinstance(q, Mapping):
        for jn, value in q.items():
            if not model.existJointName(str(jn)):
                raise tree.error(f"q names unknown or fixed joint {jn!r}{_hint(jn, list(model.names[1:]))}")
            jm = model.joints[model.getJointId(str(jn))]
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise tree.error(f"q[{jn!r}] = {value!r} is not a number") from None
            if not np.isfinite(v):
                raise tree.error(f"q[{jn!r}] is not finite")
            if jm.nv == 0:  # a mimic joint: Pinocchio drives it from its leader
                raise tree.error(f"q[{jn!r}]: a mimic joint follows its leader joint; give the leader's value")
            if jm.nq == 1:
                q0[jm.idx_q] = v
            elif jm.nq == 2 and jm.nv == 1:  # continuous joint: (cos, sin)
                q0[jm.idx_q : jm.idx_q + 2] = np.cos(v), np.sin(v)
            else:
                raise tree.error(f"q[{jn!r}]: joint has {jm.nv} degrees of freedom; pass an array of length nq")
        return q0
    try:
        arr = np.asarray(q, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise tree.error(f"q is not numeric: {q!r}") from None
    if not np.isfinite(arr).all():
        raise tree.error("q has non-finite entries")
    if arr.size == model.nq:
        return pin.normalize(model, arr)
    if arr.size == model.nv:
        return pin.integrate(model, pin.neutral(model), arr)
    raise tree.error(f"q has {arr.size} entries; this robot has nq={model.nq}, nv={model.nv} (Pinocchio order)")


def _random_configurations(model: Any, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, nq) configurations within the limits (angles of unlimited joints in [-pi, pi])."""
    import pinocchio as pin

    lo = np.maximum(model.lowerPositionLimit, -np.pi)
    hi = np.minimum(model.upperPositionLimit, np.pi)
    qs = np.tile(pin.neutral(model), (n, 1))
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.nq == 1:
            qs[:, jm.idx_q] = rng.uniform(lo[jm.idx_q], hi[jm.idx_q], n)
        elif jm.nq == 2 and jm.nv == 1:
            a = rng.uniform(-np.pi, np.pi, n)
            qs[:, jm.idx_q], qs[:, jm.idx_q + 1] = np.cos(a), np.sin(a)
    return qs


def _variable_bones(chain: KinematicChain, model: Any, q_rest: np.ndarray) -> list[tuple[str, str]]:
    qs = np.vstack([q_rest, _random_configurations(model, 6, np.random.default_rng(0))])
    lengths = chain.bone_lengths(point_positions(chain, qs, model=model))
    spread = np.ptp(lengths, axis=0)
    return [chain.links[k] for k in np.flatnonzero(spread > _VARIABLE_BONE_TOL)]


# ---------------------------------------------------------------------------- Pinocchio
def _with_extra_frames(model: Any, extra_frames: Mapping[str, Any], *, source: object = None) -> Any:
    import pinocchio as pin

    if not extra_frames:
        return model
    model = model.copy()
    for n, (parent, xyz) in extra_frames.items():
        if model.existFrame(n):
            continue
        if not model.existFrame(parent, pin.FrameType.BODY):
            raise DescriptionError(located(f"extra frame {n!r}: parent link {parent!r} is not in the model", source))
        f = model.frames[model.getFrameId(parent, pin.FrameType.BODY)]
        placement = f.placement * pin.SE3(np.eye(3), np.asarray(xyz, dtype=float))
        model.addFrame(pin.Frame(n, f.parentJoint, model.getFrameId(parent, pin.FrameType.BODY), placement, pin.FrameType.OP_FRAME))
    return model


def pinocchio_model(chain: KinematicChain) -> Any:
    """Pinocchio model of the URDF a chain came from, with its extra frames added.

    Every point of the chain is then a frame of the model: ``model.getFrameId(point)``. The
    configuration order is that of ``chain.metadata["q_rest"]``.
    """
    import pinocchio as pin  # noqa: F401 - fail early with a clear ImportError

    meta = chain.metadata
    if meta.get("kind") != "urdf" or "urdf_path" not in meta:
        raise DescriptionError(f"{chain.name} was not made by from_urdf: it has no URDF to build a model from")
    model = _build_model(Path(meta["urdf_path"]))
    return _with_extra_frames(model, meta.get("extra_frames", {}), source=meta["urdf_path"])


def point_positions(chain: KinematicChain, q: Any, *, model: Any = None) -> np.ndarray:
    """Positions (..., J, 3) in metres of a URDF chain's points at configurations ``q`` (..., nq).

    ``q`` is in Pinocchio order (``chain.metadata["q_rest"]``). ``model`` (from
    :func:`pinocchio_model`) saves rebuilding it on every call.
    """
    import pinocchio as pin

    model = pinocchio_model(chain) if model is None else model
    qs = np.asarray(q, dtype=float)
    if qs.shape[-1:] != (model.nq,):
        raise DescriptionError(f"q has shape {qs.shape}; expected (..., {model.nq}) for {chain.name}")
    ids = []
    for p in chain.joints:
        if model.existFrame(p, pin.FrameType.BODY):  # a link; a joint may share its name
            ids.append(model.getFrameId(p, pin.FrameType.BODY))
        elif model.existFrame(p):
            ids.append(model.getFrameId(p))
        else:
            raise DescriptionError(f"point {p!r} of {chain.name} is not a frame of the Pinocchio model")
    data = model.createData()
    flat = qs.reshape(int(np.prod(qs.shape[:-1])), model.nq)  # explicit rows: nq may be 0 (one link)
    out = np.empty((flat.shape[0], len(ids), 3))
    for f, qf in enumerate(flat):  # Pinocchio's kinematics run one configuration at a time
        pin.framesForwardKinematics(model, data, qf)
        out[f] = [data.oMf[i].translation for i in ids]
    return out.reshape(qs.shape[:-1] + (len(ids), 3))



# ---------------------------------------------------------------------------- meshes
def _package_name(folder: Path) -> str | None:
    """The <name> in ``folder/package.xml``, if there is one."""
    xml = folder / "package.xml"
    if not xml.is_file():
        return None
    m = re.search(r"<name>\s*([^<\s]+)\s*</name>", xml.read_text(encoding="utf-8", errors="replace"))
    return m.group(1) if m else None


def _package_roots(package: str, urdf_path: str | Path | None) -> list[Path]:
    """:func:`_find_package_roots`, remembered per package, URDF folder and ROS_PACKAGE_PATH (a URDF
    names the same package for each of its meshes)."""
    folder = None if urdf_path is None else str(Path(urdf_path).resolve().parent)
    return list(_find_package_roots(package, folder, os.environ.get("ROS_PACKAGE_PATH", "")))


@functools.lru_cache(maxsize=256)
def _find_package_roots(package: str, urdf_folder: str | None, ros_package_path: str) -> tuple[Path, ...]:
    """Folders that may be ROS package ``package``, in the order ROS tools would look: the entries of
    ROS_PACKAGE_PATH (and their sub-folders two levels down), the URDF's own ancestors (a folder named
    ``package``, one whose package.xml names it, or one holding a folder ``package``), and the share
    folder of an installed example-robot-data."""
    found: list[Path] = []

    def consider(folder: Path) -> None:
        if folder.is_dir() and (folder.name == package or _package_name(folder) == package):
            found.append(folder)

    for entry in filter(None, ros_package_path.split(os.pathsep)):
        root = Path(entry)
        if not root.is_dir():
            continue
        consider(root)
        consider(root / package)
        with contextlib.suppress(OSError):
            for sub in root.iterdir():
                if sub.is_dir():
                    consider(sub / package)
                    consider(sub)
    if urdf_folder is not None:
        for anc in (Path(urdf_folder), *Path(urdf_folder).parents):
            consider(anc)
            consider(anc / package)
    with contextlib.suppress(Exception):
        from .descriptions import _example_robot_data_root

        robots = _example_robot_data_root()
        if robots is not None:  # share/example-robot-data/robots/<pkg>, share/<pkg>
            for folder in (robots / package, robots.parent.parent / package):
                consider(folder)
    return tuple(dict.fromkeys(found))


def resolve_mesh(uri: str, urdf_path: str | Path | None = None) -> Path | None:
    """The file a URDF mesh ``filename`` names, found as ROS tools find it, or None when it is missing.

    ``package://pkg/rel`` is looked up in the folders of ROS_PACKAGE_PATH, among the URDF's ancestors
    (a folder named ``pkg`` or whose package.xml names ``pkg``, or holding a folder ``pkg``) and in the
    installed example-robot-data package; ``file://`` URIs and absolute paths are taken as they are;
    relative paths are relative to the URDF's folder.
    """
    uri = str(uri).strip()
    base = Path(urdf_path).resolve().parent if urdf_path is not None else Path.cwd()
    if uri.startswith("package://"):
        rest = uri[len("package://"):]
        package, _, rel = rest.partition("/")
        if not package or not rel:
            return None
        for root in _package_roots(package, urdf_path):
            candidate = root / rel
            if candidate.is_file():
                return candidate
        return None
    if uri.startswith("file://"):
        from urllib.parse import unquote, urlparse

        candidate = Path(unquote(urlparse(uri).path))
    elif "://" in uri:
        return None  # http:// and others: not fetched
    else:
        candidate = Path(uri)
        if not candidate.is_absolute():
            candidate = base / candidate
    return candidate if candidate.is_file() else None


def _placeholder_geometry(el: Any, link: Any, root: Any) -> None:
    """Replace the <geometry> of visual ``el`` of ``link`` by a cylinder from the link's origin to its
    first child joint's origin (a small sphere on a link with no child), at the visual's own colour."""
    from lxml import etree

    offset = None
    for joint in root.findall("joint"):
        parent = joint.find("parent")
        if parent is not None and parent.get("link") == link.get("name"):
            origin = joint.find("origin")
            xyz = [0.0, 0.0, 0.0] if origin is None else [float(v) for v in origin.get("xyz", "0 0 0").split()]
            if np.linalg.norm(xyz) > 1e-6:
                offset = np.asarray(xyz, dtype=float)
                break
    geometry = el.find("geometry")
    for child in list(geometry):
        geometry.remove(child)
    origin = el.find("origin")
    if origin is None:
        origin = etree.SubElement(el, "origin")
    if offset is None:
        etree.SubElement(geometry, "sphere", radius="0.02")
        origin.set("xyz", "0 0 0")
        origin.set("rpy", "0 0 0")
        return
    length = float(np.linalg.norm(offset))
    u = offset / length
    # rotate the cylinder's z axis onto u: pitch about y, then yaw about z (URDF rpy is fixed-axis x, y, z)
    pitch, yaw = float(np.arccos(np.clip(u[2], -1.0, 1.0))), float(np.arctan2(u[1], u[0]))
    etree.SubElement(geometry, "cylinder", radius=f"{max(0.01, 0.08 * length):.4f}", length=f"{length:.6f}")
    origin.set("xyz", " ".join(f"{v:.6f}" for v in offset / 2))
    origin.set("rpy", f"0 {pitch:.6f} {yaw:.6f}")


def visual_urdf(urdf_path: str | Path) -> str:
    """The URDF's XML with every visual mesh's filename resolved (:func:`resolve_mesh`) to an absolute
    path; a mesh that cannot be found is drawn as a primitive instead (a cylinder along the link, or a
    sphere), with one warning naming the missing meshes. Collision geometry is dropped (not drawn)."""
    from lxml import etree

    path = Path(urdf_path)
    root = etree.parse(str(path), etree.XMLParser(remove_comments=True, resolve_entities=False)).getroot()
    missing: list[str] = []
    for link in root.findall("link"):
        for col in link.findall("collision"):
            link.remove(col)
        for vis in link.findall("visual"):
            mesh = vis.find("geometry/mesh")
            if mesh is None:
                continue
            uri = mesh.get("filename", "")
            found = resolve_mesh(uri, path)
            if found is not None:
                mesh.set("filename", str(found))
            else:
                missing.append(uri)
                _placeholder_geometry(vis, link, root)
    if missing:
        shown = ", ".join(dict.fromkeys(missing[:3])) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        warnings.warn(f"{path.name}: mesh {shown} not found (searched ROS_PACKAGE_PATH, the URDF's folders "
                      "and example-robot-data); drawn as simple shapes instead", stacklevel=2)
    return etree.tostring(root, encoding="unicode")
