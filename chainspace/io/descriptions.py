"""Finding and loading chain descriptions: files by extension, shipped names, example robots.

Shipped descriptions live in the package ``chainspace.robots`` (the repository's ``robots/``
folder), so they are found from an installed chainspace too. ``example_robot_urdf`` finds the URDFs
of the ``example-robot-data`` package (UR, Panda, xArm, ...), which installs data files only.
"""

from __future__ import annotations

import difflib
import importlib
import importlib.metadata
import importlib.resources
import inspect
import sys
from pathlib import Path
from typing import Any

from ..chain import KinematicChain
from ..errors import ChainspaceError, DescriptionError, DescriptionNotFoundError

__all__ = ["load_chain", "shipped", "shipped_path", "list_shipped", "example_robot_urdf", "EXAMPLE_ROBOTS",
           "description_path"]

# extension -> (module, loader function); modules are imported when first needed
_LOADERS = {
    ".urdf": ("urdf", "from_urdf"),
    ".asf": ("asf", "from_asf"),
    ".bvh": ("bvh", "from_bvh"),
    ".toml": ("skeleton_file", "from_skeleton_file"),
    ".yaml": ("skeleton_file", "from_skeleton_file"),
    ".yml": ("skeleton_file", "from_skeleton_file"),
}

# example-robot-data name -> URDF path under share/example-robot-data/robots
EXAMPLE_ROBOTS = {
    "ur3": "ur_description/urdf/ur3_robot.urdf",
    "ur5": "ur_description/urdf/ur5_robot.urdf",
    "ur10": "ur_description/urdf/ur10_robot.urdf",
    "panda": "panda_description/urdf/panda.urdf",
    "xarm7": "xarm_description/urdf/xarm7.urdf",
    "kinova": "kinova_description/robots/kinova.urdf",
    "talos_arm": "talos_data/robots/talos_left_arm.urdf",
    "z1": "z1_description/urdf/z1.urdf",
    "so100": "so_arm_description/urdf/so100.urdf",
    "so101": "so_arm_description/urdf/so101.urdf",
    "baxter": "baxter_description/urdf/baxter.urdf",
    "a1": "a1_description/urdf/a1.urdf",
    "go1": "go1_description/urdf/go1.urdf",
    "solo12": "solo_description/robots/solo12.urdf",
    "laikago": "laikago_description/urdf/laikago.urdf",
    "double_pendulum": "double_pendulum_description/urdf/double_pendulum.urdf",
}


def _loader(suffix: str) -> Any:
    module, func = _LOADERS[suffix]
    return getattr(importlib.import_module(f".{module}", __package__), func)


def list_shipped() -> list[str]:
    """Names (with extension) of the descriptions shipped in ``chainspace.robots``, sorted."""
    root = importlib.resources.files("chainspace.robots")
    return sorted(p.name for p in root.iterdir() if p.is_file() and Path(p.name).suffix in _LOADERS)


def shipped_path(name: str) -> Path:
    """Path of a shipped description, by name with or without extension (``"milling_arm"``)."""
    if not isinstance(name, str) or not name:
        raise DescriptionNotFoundError(f"a shipped description name is a non-empty string, not {name!r}")
    available = list_shipped()
    matches = [n for n in available if n == name or Path(n).stem == name]
    if not matches and name in EXAMPLE_ROBOTS:
        raise DescriptionNotFoundError(f"{name!r} is an example-robot-data robot, not a description shipped with "
                                       f"chainspace: use chainspace.load_chain({name!r})")
    if not matches:
        raise DescriptionNotFoundError(_unknown_name(name, available))
    if len(matches) > 1:
        raise DescriptionError(f"{name!r} is ambiguous: {', '.join(matches)}; give the extension")
    resource = importlib.resources.files("chainspace.robots") / matches[0]
    # An installed package is a folder on disk (setuptools package data), so this is a real path.
    return Path(str(resource))


def _unknown_name(name: str, available: list[str]) -> str:
    """No description is called ``name``: what is, by name, and the names close to it (shipped or
    example-robot-data, as ``--chain`` takes them)."""
    stems = [Path(n).stem for n in available]
    close = difflib.get_close_matches(name, stems + list(EXAMPLE_ROBOTS), n=3)
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    return (f"no shipped description {name!r}; available: {', '.join(available) or '(none)'}. Robots of "
            f"example-robot-data by name: {', '.join(EXAMPLE_ROBOTS)}.{hint}")


def shipped(name: str, **kwargs: Any) -> KinematicChain:
    """Load a shipped description (``"milling_arm"``, ``"human17"``, ...); ``kwargs`` go to its loader."""
    return load_chain(shipped_path(name), **kwargs)


def load_chain(path_or_name: str | Path, **kwargs: Any) -> KinematicChain:
    """Load a chain from a description file, chosen by extension, or a shipped name.

    ``.urdf`` -> :func:`chainspace.from_urdf`, ``.asf`` -> :func:`chainspace.from_asf`, ``.bvh`` ->
    :func:`chainspace.from_bvh`, ``.toml``/``.yaml``/``.yml`` -> :func:`chainspace.from_skeleton_file`.
    A string that is not an existing file and has no path separator is looked up among the shipped
    descriptions (:func:`list_shipped`), then among the example-robot-data URDFs
    (:data:`EXAMPLE_ROBOTS`, :func:`example_robot_urdf`). ``kwargs`` go to the loader.
    """
    path = description_path(path_or_name)
    suffix = path.suffix.lower()
    if suffix not in _LOADERS:
        raise DescriptionError(
            f"{path}: unknown description format {suffix or '(no extension)'!r}; "
            f"known: {', '.join(sorted(_LOADERS))}"
        )
    loader = _loader(suffix)
    try:  # an unknown option is the caller's mistake: say so rather than raise a bare TypeError
        inspect.signature(loader).bind(path, **kwargs)
    except TypeError as exc:
        raise DescriptionError(f"{path}: {loader.__name__} does not take these options: {exc}") from None
    return loader(path, **kwargs)


def description_path(path_or_name: str | Path) -> Path:
    """The file of a description: an existing file, a shipped name (``"milling_arm"``) or an
    example-robot-data robot (``"ur5"``, :data:`EXAMPLE_ROBOTS`); else :class:`DescriptionNotFoundError`."""
    if not isinstance(path_or_name, (str, Path)):
        raise DescriptionError(f"expected a file path or a shipped name, not {type(path_or_name).__name__}")
    path = Path(path_or_name)
    if path.is_file():
        return path
    text = str(path_or_name)
    if not (isinstance(path_or_name, str) and "/" not in text and "\\" not in text and text):
        raise DescriptionNotFoundError(f"description file not found: {path}")
    try:
        return shipped_path(text)
    except DescriptionNotFoundError as exc:
        if text in EXAMPLE_ROBOTS:
            try:
                return example_robot_urdf(text)
            except ChainspaceError as missing:  # the package or its file is not there: say which
                raise DescriptionNotFoundError(str(missing)) from None
        if path.suffix.lower() in _LOADERS:
            raise DescriptionNotFoundError(f"description file not found: {path}") from None
        raise DescriptionNotFoundError(str(exc)) from None


def _example_robot_data_root() -> Path | None:
    """``share/example-robot-data/robots`` of the installed example-robot-data package, if any."""
    candidates = []
    try:
        for f in importlib.metadata.files("example-robot-data") or ():
            parts = Path(f.locate()).resolve().parts
            for k in range(1, len(parts) - 1):
                if parts[k - 1] == "example-robot-data" and parts[k] == "robots":
                    candidates.append(Path(*parts[: k + 1]))
                    break
            if candidates:
                break
    except importlib.metadata.PackageNotFoundError:
        pass
    for prefix in (sys.prefix, sys.base_prefix):
        for sub in ("cmeel.prefix/share", "share"):
            for lib in Path(prefix).glob(f"lib/python*/site-packages/{sub}/example-robot-data/robots"):
                candidates.append(lib)
            candidates.append(Path(prefix) / sub / "example-robot-data" / "robots")
    return next((c for c in candidates if c.is_dir()), None)


def example_robot_urdf(name: str) -> Path:
    """Path of an example-robot-data URDF by short name (``"ur10"``, ``"panda"``, ``"xarm7"``, ...).

    Names: see :data:`EXAMPLE_ROBOTS`. Raises :class:`ChainspaceError` when the package
    (``pip install example-robot-data``) or the file is missing.
    """
    if name not in EXAMPLE_ROBOTS:
        close = difflib.get_close_matches(str(name), list(EXAMPLE_ROBOTS), n=3)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise ChainspaceError(f"unknown example robot {name!r}; known: {', '.join(EXAMPLE_ROBOTS)}.{hint}")
    root = _example_robot_data_root()
    if root is None:
        raise ChainspaceError(
            "the example-robot-data package is not installed (pip install example-robot-data); "
            f"it provides the {name!r} URDF"
        )
    path = root / EXAMPLE_ROBOTS[name]
    if not path.is_file():
        raise ChainspaceError(f"example-robot-data has no {EXAMPLE_ROBOTS[name]} (looked in {root})")
    return path
