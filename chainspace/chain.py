"""The kinematic chain: joints, bones, and the matrices of the Kinematic Chain Space.

Notation (Wandt, Ackermann and Rosenhahn, "A Kinematic Chain Space for Monocular Motion Capture",
2017). A pose X is 3 x J, one column per joint. The chain gives

* ``C`` (J x L): one column per link, +1 at the link's child joint and -1 at its parent, so the bone
  vectors of a pose are ``B = X C`` (3 x L). The first ``n_bones`` links are the bones of the tree;
  the remaining ones are *rigid links*: extra joint pairs whose distance is constant (two hands on one
  sword), which constrain the reconstruction without being part of the tree.
* ``D`` (n_bones x J): ``D[b, j] = 1`` when tree bone b lies on the path from the root to joint j, so
  ``X = B D`` rebuilds the pose from its tree bones with the root at the origin.

The API is frames-first: poses are (F, J, 3) arrays, bones (F, L, 3). Units are whatever the pose
uses; descriptions shipped with chainspace are in metres.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from functools import cached_property
from typing import Any

import numpy as np

from .errors import DescriptionError, TrackError, located

__all__ = ["KinematicChain"]


class KinematicChain:
    """A tree of joints connected by bones, plus optional rigid links.

    Parameters
    ----------
    joints
        Unique joint names, in the order used by every array of this chain.
    bones
        ``(parent, child)`` name pairs. They must form one tree over all joints: every joint but the
        root has exactly one parent, and every joint is reachable from the root.
    rest_pose
        Optional (J, 3) joint positions in metres: a plausible neutral pose, used as the default
        initial pose of a reconstruction.
    rigid_links
        Extra ``(joint_a, joint_b)`` pairs whose distance stays constant. They add columns to ``C`` and
        none to ``D``.
    name
        A short human-readable name.
    source
        Where the description came from (a path), quoted in error messages.
    metadata
        Free-form facts a loader wants to keep (the URDF path, the links merged into one point, ...).
    """

    def __init__(
        self,
        joints: Sequence[str],
        bones: Iterable[tuple[str, str]],
        rest_pose: Any = None,
        rigid_links: Iterable[tuple[str, str]] = (),
        *,
        name: str | None = None,
        source: object = None,
        metadata: Mapping[str, Any] | None = None,
    ) -> None:
        self.source = source
        self.name = name or (str(source) if source is not None else "chain")
        self.metadata = dict(metadata or {})
        self._joints = self._check_joints(joints)
        self._index = {j: i for i, j in enumerate(self._joints)}
        self._bones = self._check_pairs(bones, "bone")
        self._rigid_links = self._check_pairs(rigid_links, "rigid link")
        self._parent = self._check_tree()
        self._check_rigid_links()
        self._rest_pose = None if rest_pose is None else self._check_rest_pose(rest_pose)

    # ------------------------------------------------------------------ validation
    def _error(self, message: str) -> DescriptionError:
        return DescriptionError(located(message, self.source))

    def _check_joints(self, joints: Sequence[str]) -> tuple[str, ...]:
        if isinstance(joints, str):
            raise self._error("joints must be a sequence of names, not one string")
        names = tuple(joints)
        if not names:
            raise self._error("the chain has no joints")
        seen: set[str] = set()
        for i, n in enumerate(names):
            if not isinstance(n, str) or not n.strip():
                raise self._error(f"joint {i} has an invalid name {n!r}: names are non-empty strings")
            if n in seen:
                raise self._error(f"joint name {n!r} appears twice")
            seen.add(n)
        return names

    def _check_pairs(self, pairs: Iterable[tuple[str, str]], kind: str) -> tuple[tuple[str, str], ...]:
        out = []
        for k, pair in enumerate(pairs):
            try:
                a, b = pair
            except (TypeError, ValueError):
                raise self._error(f"{kind} {k} is {pair!r}, not a (parent, child) pair of names") from None
            for n in (a, b):
                if n not in self._index:
                    raise self._error(f"{kind} {k} ({a!r}, {b!r}) names unknown joint {n!r}{self._hint(n)}")
            if a == b:
                raise self._error(f"{kind} {k} joins joint {a!r} to itself")
            out.append((a, b))
        return tuple(out)

    def _hint(self, name: object) -> str:
        close = difflib.get_close_matches(str(name), self._joints, n=3)
        return f" (did you mean {', '.join(map(repr, close))}?)" if close else ""

    def _check_tree(self) -> np.ndarray:
        parent = np.full(len(self._joints), -1)
        for a, b in self._bones:
            ia, ib = self._index[a], self._index[b]
            if parent[ib] >= 0:
                raise self._error(
                    f"joint {b!r} has two parents ({self._joints[parent[ib]]!r} and {a!r}): a cycle or a "
                    "second path; declare the extra connection as a rigid link"
                )
            parent[ib] = ia
        roots = [self._joints[i] for i in np.flatnonzero(parent < 0)]
        if not roots:
            raise self._error("the bones form a cycle: no joint is without a parent")
        if len(roots) > 1:
            raise self._error(
                f"the chain is disconnected: {len(roots)} joints have no parent ({', '.join(roots[:8])}"
                f"{', ...' if len(roots) > 8 else ''}); bones must connect every joint to one root"
            )
        # One root and one parent each: a joint not reached from the root sits on a cycle.
        depth = np.full(len(parent), -1)
        depth[parent < 0] = 0
        for _ in range(len(parent)):
            todo = (depth < 0) & (depth[parent] >= 0)
            if not todo.any():
                break
            depth[todo] = depth[parent[todo]] + 1
        if (depth < 0).any():
            cyc = [self._joints[i] for i in np.flatnonzero(depth < 0)]
            raise self._error(f"the bones form a cycle through joints {', '.join(cyc[:8])}")
        self._depth = depth
        return parent

    def _check_rigid_links(self) -> None:
        bones = {frozenset(p) for p in self._bones}
        seen: set[frozenset] = set()
        for a, b in self._rigid_links:
            key = frozenset((a, b))
            if key in bones:
                raise self._error(f"rigid link ({a!r}, {b!r}) repeats a bone")
            if key in seen:
                raise self._error(f"rigid link ({a!r}, {b!r}) is given twice")
            seen.add(key)

    def _check_rest_pose(self, rest_pose: Any) -> np.ndarray:
        try:
            pose = np.array(rest_pose, dtype=float)
        except (TypeError, ValueError) as exc:
            raise self._error(f"rest pose is not numeric: {exc}") from None
        if pose.shape != (self.n_joints, 3):
            raise self._error(f"rest pose has shape {pose.shape}, expected ({self.n_joints}, 3)")
        bad = ~np.isfinite(pose).all(axis=1)
        if bad.any():
            raise self._error(f"rest pose of joint {self._joints[np.flatnonzero(bad)[0]]!r} is not finite")
        pose.setflags(write=False)
        return pose

    # ------------------------------------------------------------------ what the chain is
    @property
    def joints(self) -> tuple[str, ...]:
        """Joint names, in array order."""
        return self._joints

    @property
    def bones(self) -> tuple[tuple[str, str], ...]:
        """Tree bones as ``(parent, child)`` names, in the order of the first columns of ``C``."""
        return self._bones

    @property
    def rigid_links(self) -> tuple[tuple[str, str], ...]:
        """Extra constant-distance joint pairs, the last columns of ``C``."""
        return self._rigid_links

    @property
    def links(self) -> tuple[tuple[str, str], ...]:
        """Bones then rigid links: the columns of ``C``."""
        return self._bones + self._rigid_links

    @property
    def n_joints(self) -> int:
        return len(self._joints)

    @property
    def n_bones(self) -> int:
        """Number of tree bones (rows of ``D``), always ``n_joints - 1``."""
        return len(self._bones)

    @property
    def n_links(self) -> int:
        """Number of columns of ``C``: bones plus rigid links."""
        return len(self._bones) + len(self._rigid_links)

    @property
    def root(self) -> str:
        """The joint without a parent."""
        return self._joints[int(np.flatnonzero(self._parent < 0)[0])]

    @property
    def parents(self) -> np.ndarray:
        """(J,) index of each joint's parent, -1 at the root."""
        return self._parent.copy()

    @property
    def rest_pose(self) -> np.ndarray | None:
        """(J, 3) neutral pose in metres, or None when the description gives none."""
        return self._rest_pose

    @cached_property
    def C(self) -> np.ndarray:  # noqa: N802 - the paper's symbol
        """(J, L) link matrix: bones ``B = X C`` for a 3 x J pose X."""
        C = np.zeros((self.n_joints, self.n_links))
        for k, (a, b) in enumerate(self.links):
            C[self._index[a], k] = -1.0
            C[self._index[b], k] = 1.0
        C.setflags(write=False)
        return C

    @cached_property
    def D(self) -> np.ndarray:  # noqa: N802 - the paper's symbol
        """(n_bones, J) path matrix: ``X = B D`` with the root at the origin."""
        bone_of_child = {self._index[b]: k for k, (_, b) in enumerate(self._bones)}
        D = np.zeros((self.n_bones, self.n_joints))
        for j in range(self.n_joints):
            i = j
            while self._parent[i] >= 0:
                D[bone_of_child[i], j] = 1.0
                i = self._parent[i]
        D.setflags(write=False)
        return D

    def joint_index(self, name: str) -> int:
        """Array index of joint ``name``; a :class:`DescriptionError` names unknown joints."""
        try:
            return self._index[name]
        except (KeyError, TypeError):
            raise self._error(f"unknown joint {name!r}{self._hint(name)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __len__(self) -> int:
        return self.n_joints

    def __repr__(self) -> str:
        extra = f", {len(self._rigid_links)} rigid links" if self._rigid_links else ""
        return f"KinematicChain({self.name!r}, {self.n_joints} joints, root {self.root!r}{extra})"

    # ------------------------------------------------------------------ maps between spaces
    def bone_vectors(self, poses: Any) -> np.ndarray:
        """Link vectors ``X C`` of poses (..., J, 3), returned as (..., L, 3)."""
        return self.C.T @ self._as_poses(poses)  # a matrix product: einsum here is ~7x slower

    def bone_lengths(self, poses: Any) -> np.ndarray:
        """Lengths of every link (bones, then rigid links) of poses (..., J, 3): (..., L)."""
        V = self.bone_vectors(poses)
        # the coordinates summed one by one: np.linalg.norm over the short last axis is 5 times slower
        return np.sqrt(V[..., 0] ** 2 + V[..., 1] ** 2 + V[..., 2] ** 2)

    def poses_from_bones(self, bones: Any) -> np.ndarray:
        """Poses (..., J, 3) with the root at the origin from tree bone vectors (..., n_bones, 3).

        Rigid-link columns, if passed (L instead of n_bones rows), are ignored.
        """
        B = np.asarray(bones, dtype=float)
        return self.D.T @ B[..., : self.n_bones, :]

    def _as_poses(self, poses: Any) -> np.ndarray:
        X = np.asarray(poses, dtype=float)
        if X.ndim < 2 or X.shape[-2:] != (self.n_joints, 3):
            raise TrackError(f"poses have shape {X.shape}, expected (..., {self.n_joints}, 3) for {self.name}")
        return X

    # ------------------------------------------------------------------ selecting and ordering
    def subset(self, joints: Sequence[str], *, name: str | None = None) -> KinematicChain:
        """The chain restricted to ``joints``, in the order given.

        Each kept joint hangs from its nearest kept ancestor, so dropping a joint in the middle of a
        limb joins its neighbours with one longer bone. Rigid links between kept joints stay. Exactly
        one kept joint may have no kept ancestor; it becomes the new root.
        """
        keep = [self.joint_index(j) for j in joints]
        if len(set(keep)) != len(keep):
            raise self._error("subset names a joint twice")
        kept = set(keep)
        bones, roots = [], []
        for i in keep:
            a = self._parent[i]
            while a >= 0 and a not in kept:
                a = self._parent[a]
            if a < 0:
                roots.append(self._joints[i])
            else:
                bones.append((self._joints[a], self._joints[i]))
        if len(roots) > 1:
            raise self._error(
                f"subset has no common root: {', '.join(map(repr, roots))} have no kept ancestor; "
                f"keep a joint they all hang from (for example {self.root!r})"
            )
        order = sorted(range(len(bones)), key=lambda k: self._depth[self._index[bones[k][1]]])
        rest = None if self._rest_pose is None else self._rest_pose[keep]
        links = [p for p in self._rigid_links if p[0] in joints and p[1] in joints]
        # the points dropped, so that tracks of them are said to be unselected rather than unknown
        left_out = list(self.metadata.get("left_out", ())) + [j for j in self._joints if j not in joints]
        return KinematicChain(
            [self._joints[i] for i in keep],
            [bones[k] for k in order],
            rest,
            links,
            name=name or self.name,
            source=self.source,
            metadata={**self.metadata, **({"left_out": left_out} if left_out else {})},
        )

    def reorder(self, values: Any, names: Sequence[str], *, axis: int = -2, fill: float = np.nan) -> np.ndarray:
        """Rearrange per-joint ``values`` given in the order ``names`` into this chain's order.

        ``values`` has one entry per name along ``axis`` (for tracks (F, N, 2), axis -2). Names that
        the chain does not have are dropped; chain joints missing from ``names`` are filled with
        ``fill`` (NaN: not seen). One call maps, for example, COCO-17 detector output onto a chain.
        """
        arr = np.asarray(values, dtype=float)
        names = list(names)
        ax = axis % arr.ndim if arr.ndim else 0
        if arr.ndim == 0 or arr.shape[ax] != len(names):
            raise TrackError(
                f"values have {arr.shape[ax] if arr.ndim else 0} entries along axis {axis} but "
                f"{len(names)} names were given"
            )
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise TrackError(f"joint names given twice: {', '.join(sorted(dup))}")
        found = [n for n in names if n in self._index]
        if not found:
            raise TrackError(
                f"none of the given names is a joint of {self.name} (given {', '.join(names[:5])}...; "
                f"the chain has {', '.join(self._joints[:5])}...)"
            )
        shape = list(arr.shape)
        shape[ax] = self.n_joints
        out = np.full(shape, fill, dtype=float)
        src = [names.index(n) for n in found]
        dst = [self._index[n] for n in found]
        idx_out = [slice(None)] * arr.ndim
        idx_in = [slice(None)] * arr.ndim
        idx_out[ax], idx_in[ax] = dst, src
        out[tuple(idx_out)] = arr[tuple(idx_in)]
        return out

    def with_rest_pose(self, rest_pose: Any) -> KinematicChain:
        """A copy of this chain with another rest pose (J, 3)."""
        return KinematicChain(
            self._joints, self._bones, rest_pose, self._rigid_links,
            name=self.name, source=self.source, metadata=self.metadata,
        )

    def with_rigid_links(self, rigid_links: Iterable[tuple[str, str]]) -> KinematicChain:
        """A copy of this chain with these rigid links added to its own."""
        return KinematicChain(
            self._joints, self._bones, self._rest_pose, self._rigid_links + tuple(rigid_links),
            name=self.name, source=self.source, metadata=self.metadata,
        )
