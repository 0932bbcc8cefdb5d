"""A small skeleton file format (TOML or YAML) for chains that have no robot description.

Schema (the same keys in TOML and YAML)::

    name = "human17"                 # optional, default: the file name
    units = "m"                      # "m", "cm", "mm" or "in"; positions are converted to metres
    up = "z"                         # "z" (chainspace's world) or "y" (turned Z-up on loading)
    description = "..."              # optional free text
    source = "..."                   # optional: where the numbers come from

    [[joints]]                       # in array order
    name = "pelvis"
    rest = [0.0, 0.0, 0.0]           # optional rest position; give it for all joints or none

    bones = [["pelvis", "left_hip"], ...]          # (parent, child); or [[bones]] tables with
                                                   # parent = "..." and child = "..."
    rigid_links = [["left_wrist", "right_wrist"]]  # optional constant-distance pairs

Errors name the file and, where it can be found, the line: the parser's own line for syntax errors,
the line where the offending name first appears for unknown joints and the like.
"""

from __future__ import annotations

import json
import re
import tomllib
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..chain import KinematicChain
from ..errors import DescriptionError, DescriptionNotFoundError, OutputExistsError, located
from .results import atomic_write

__all__ = ["from_skeleton_file", "save_skeleton_file", "UNITS"]

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
_Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # (x, y, z) -> (x, -z, y)
_KEYS = {"name", "units", "up", "description", "source", "joints", "bones", "rigid_links"}


def _kind(path: Path) -> str:
    ext = path.suffix.lower()
    if ext == ".toml":
        return "toml"
    if ext in (".yaml", ".yml"):
        return "yaml"
    raise DescriptionError(f"{path}: a skeleton file ends in .toml, .yaml or .yml")


def _parse(text: str, kind: str, src: str) -> dict:
    if kind == "toml":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
            msg = re.sub(r"\s*\(at line.*\)$", "", str(exc))
            raise DescriptionError(located(f"TOML syntax error: {msg}", src, int(m.group(1)) if m else None)) from None
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.MarkedYAMLError as exc:
            line = exc.problem_mark.line + 1 if exc.problem_mark else None
            raise DescriptionError(located(f"YAML syntax error: {exc.problem}", src, line)) from None
        except yaml.YAMLError as exc:
            raise DescriptionError(located(f"YAML error: {exc}", src)) from None
    if not isinstance(data, dict):
        raise DescriptionError(located("the file must hold a table of keys (name, joints, bones, ...)", src))
    return data


class _Where:
    """Finds the line where a name first appears, for error messages."""

    def __init__(self, text: str, src: str) -> None:
        self.lines, self.src = text.splitlines(), src

    def line(self, token: object, occurrence: int = 1) -> int | None:
        needles = [f'"{token}"', f"'{token}'", f"{token}"]
        for needle in needles:
            hits = [no for no, text in enumerate(self.lines, 1) if needle in text.split("#", 1)[0]]
            if len(hits) >= occurrence:
                return hits[occurrence - 1]
        return None

    def error(self, message: str, token: object = None, occurrence: int = 1) -> DescriptionError:
        line = self.line(token, occurrence) if token is not None else None
        return DescriptionError(located(message, self.src, line))


def _pairs(value: Any, key: str, where: _Where) -> list[tuple[str, str]]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise where.error(f"'{key}' must be a list of (parent, child) pairs", key)
    out = []
    for k, item in enumerate(value):
        if isinstance(item, dict):
            extra = set(item) - {"parent", "child"}
            if extra or len(item) != 2:
                raise where.error(f"{key} entry {k} needs exactly 'parent' and 'child', got {sorted(item)}", key)
            item = [item["parent"], item["child"]]
        if not (isinstance(item, list) and len(item) == 2 and all(isinstance(n, str) for n in item)):
            raise where.error(f"{key} entry {k} is {item!r}, not a pair of joint names", key)
        out.append((item[0], item[1]))
    return out


def _joints(value: Any, where: _Where, scale: float) -> tuple[list[str], np.ndarray | None]:
    if not isinstance(value, list) or not value:
        raise where.error("'joints' must be a non-empty list of tables with 'name' (and 'rest')", "joints")
    names, rests = [], []
    for k, item in enumerate(value):
        if isinstance(item, str):
            item = {"name": item}
        if not isinstance(item, dict) or not isinstance(item.get("name"), str):
            raise where.error(f"joint {k} is {item!r}: each joint needs a 'name' string", "joints")
        extra = set(item) - {"name", "rest"}
        if extra:
            raise where.error(f"joint {item['name']!r} has unknown keys {sorted(extra)}", item["name"])
        if item["name"] in names:
            raise where.error(f"joint name {item['name']!r} appears twice", item["name"], occurrence=2)
        names.append(item["name"])
        rest = item.get("rest")
        if rest is not None:
            ok = isinstance(rest, list) and len(rest) == 3 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in rest)
            if not ok or not np.isfinite(np.array(rest, dtype=float)).all():
                raise where.error(f"joint {item['name']!r}: rest must be three finite numbers, got {rest!r}",
                                  item["name"])
        rests.append(rest)
    given = [r is not None for r in rests]
    if any(given) and not all(given):
        missing = names[given.index(False)]
        raise where.error(f"joint {missing!r} has no rest position: give one for every joint or none", missing)
    return names, (np.array(rests, dtype=float) * scale if all(given) else None)


def from_skeleton_file(path: str | PathLike) -> KinematicChain:
    """Read a TOML or YAML skeleton file (see the module docstring) as a chain, metres, Z-up."""
    p = Path(str(path))
    if not p.is_file():
        raise DescriptionNotFoundError(f"{p}: skeleton file not found")
    kind, src = _kind(p), str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DescriptionError(f"{src}: cannot read: {exc}") from None
    if not text.strip():
        raise DescriptionError(f"{src}: the skeleton file is empty")
    data = _parse(text, kind, src)
    where = _Where(text, src)
    unknown = set(data) - _KEYS
    if unknown:
        key = sorted(unknown, key=str)[0]
        raise where.error(f"unknown key {key!r}; allowed: {', '.join(sorted(_KEYS))}", str(key))
    units = data.get("units", "m")
    if not isinstance(units, str) or units not in UNITS:
        raise where.error(f"units {units!r} must be one of {', '.join(UNITS)}", "units")
    up = data.get("up", "z")
    if not isinstance(up, str) or up not in ("z", "y"):
        raise where.error(f"up {up!r} must be 'z' or 'y'", "up")
    joints, rest = _joints(data.get("joints"), where, UNITS[units])
    if rest is not None and up == "y":
        rest = rest @ _Y_TO_Z.T
    bones = _pairs(data.get("bones"), "bones", where)
    links = _pairs(data.get("rigid_links"), "rigid_links", where)
    for a, b in bones + links:
        for n in (a, b):
            if n not in joints:
                raise where.error(f"bone ({a!r}, {b!r}) names unknown joint {n!r}", n)
    meta = {"kind": "skeleton_file", "path": src, "units": units, "up": up}
    for key in ("description", "source"):
        if key in data:
            meta[key] = str(data[key])
    try:
        return KinematicChain(joints, bones, rest, links, name=str(data.get("name", p.stem)), source=src,
                              metadata=meta)
    except DescriptionError as exc:
        # The chain names the offending joint between quotes; point at its line when it can.
        m = re.search(r"'([^']+)'", str(exc))
        line = where.line(m.group(1)) if m else None
        raise DescriptionError(located(str(exc).removeprefix(f"{src}: "), src, line)) from None


# ------------------------------------------------------------------------------------------ writing
def _toml_str(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)  # a JSON string is a valid TOML basic string


def _num(v: float) -> str:
    return repr(round(float(v), 6) + 0.0)  # + 0.0 turns -0.0 into 0.0


def _as_toml(d: dict) -> str:
    out = []
    for key in ("name", "units", "up", "description", "source"):
        if key in d:
            out.append(f"{key} = {_toml_str(d[key])}")
    out.append("")
    for j in d["joints"]:
        out.append("[[joints]]")
        out.append(f"name = {_toml_str(j['name'])}")
        if "rest" in j:
            out.append(f"rest = [{', '.join(_num(v) for v in j['rest'])}]")
        out.append("")
    for key in ("bones", "rigid_links"):
        if d.get(key):
            # Top-level keys must come before the first table, so pairs are written as tables.
            for a, b in d[key]:
                out.append(f"[[{key}]]")
                out.append(f"parent = {_toml_str(a)}\nchild = {_toml_str(b)}")
                out.append("")
    return "\n".join(out)


def save_skeleton_file(chain: KinematicChain, path: str | PathLike, overwrite: bool = False,
                       *, description: str | None = None, source: str | None = None) -> Path:
    """Write ``chain`` as a TOML or YAML skeleton file (by extension), metres, Z-up.

    Refuses to replace an existing file unless ``overwrite``; writes a temporary file and renames it,
    so an interrupted write leaves nothing half-written. Returns the path.
    """
    p = Path(path)
    kind = _kind(p)
    if p.exists() and not overwrite:
        raise OutputExistsError(f"{p}: exists; pass overwrite=True to replace it")
    meta = chain.metadata
    d: dict[str, Any] = {"name": chain.name, "units": "m", "up": "z"}
    for key, val in (("description", description or meta.get("description")),
                     ("source", source or meta.get("source"))):
        if val:
            d[key] = str(val)
    rest = chain.rest_pose
    d["joints"] = [{"name": j} | ({"rest": [round(float(v), 6) for v in rest[i]]} if rest is not None else {})
                   for i, j in enumerate(chain.joints)]
    d["bones"] = [list(b) for b in chain.bones]
    if chain.rigid_links:
        d["rigid_links"] = [list(b) for b in chain.rigid_links]
    if kind == "toml":
        text = _as_toml(d)
    else:
        text = yaml.safe_dump(d, sort_keys=False, default_flow_style=None, allow_unicode=True)
    with atomic_write(p, "w", overwrite) as fh:
        fh.write(text)
    return p
