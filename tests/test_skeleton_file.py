"""Skeleton files (TOML / YAML): round trips, the shipped skeletons, errors with file:line."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from chainspace import (
    DescriptionError,
    DescriptionNotFoundError,
    KinematicChain,
    OutputExistsError,
    from_skeleton_file,
    save_skeleton_file,
)

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
SHIPPED = ["human17.toml", "coco17.toml", "horse.toml"]


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_skeletons_load_with_a_rest_pose(name):
    chain = from_skeleton_file(ROBOTS / name)
    assert chain.rest_pose is not None and chain.n_bones == chain.n_joints - 1
    assert chain.metadata["source"] and chain.metadata["description"]
    X = chain.rest_pose
    assert np.all(chain.bone_lengths(X) > 0.01)  # no degenerate bones
    # (X C) D rebuilds X minus its root
    assert np.allclose(chain.poses_from_bones(chain.bone_vectors(X)), X - X[chain.joint_index(chain.root)])


def test_coco17_names_and_proportions():
    coco = from_skeleton_file(ROBOTS / "coco17.toml")
    assert coco.joints == (
        "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
        "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
        "right_knee", "left_ankle", "right_ankle",
    )
    h17 = from_skeleton_file(ROBOTS / "human17.toml")
    for a, b in [("left_hip", "left_knee"), ("left_knee", "left_ankle"), ("left_elbow", "left_wrist")]:
        la = np.linalg.norm(np.subtract(*coco.rest_pose[[coco.joint_index(a), coco.joint_index(b)]]))
        lb = np.linalg.norm(np.subtract(*h17.rest_pose[[h17.joint_index(a), h17.joint_index(b)]]))
        assert la == pytest.approx(lb, rel=1e-6)
    X = coco.rest_pose
    assert X[coco.joint_index("nose")][2] > X[coco.joint_index("left_shoulder")][2] > X[coco.joint_index("left_hip")][2]


def test_horse_height():
    horse = from_skeleton_file(ROBOTS / "horse.toml")
    X = horse.rest_pose
    hooves = [j for j in horse.joints if j.endswith("hoof")]
    assert len(hooves) == 4 and 20 <= horse.n_joints <= 26
    assert np.allclose(X[[horse.joint_index(h) for h in hooves], 2], 0.0, atol=0.02)  # standing on z = 0
    assert X[horse.joint_index("withers"), 2] == pytest.approx(1.6, abs=0.05)


@pytest.mark.parametrize("ext", [".toml", ".yaml"])
def test_round_trip(tmp_path, ext):
    rng = np.random.default_rng(0)
    chain = KinematicChain(
        ["a", "b", "c", "d"], [("a", "b"), ("b", "c"), ("a", "d")], rng.normal(size=(4, 3)).round(6),
        [("c", "d")], name="toy",
    )
    path = save_skeleton_file(chain, tmp_path / f"toy{ext}", description="a toy \"quoted\"", source="made up")
    back = from_skeleton_file(path)
    assert back.joints == chain.joints and back.bones == chain.bones and back.rigid_links == chain.rigid_links
    assert np.allclose(back.rest_pose, chain.rest_pose, atol=1e-12)
    assert back.name == "toy" and back.metadata["description"] == 'a toy "quoted"'
    with pytest.raises(OutputExistsError):
        save_skeleton_file(chain, path)
    save_skeleton_file(chain.with_rest_pose(chain.rest_pose * 2), path, overwrite=True)
    assert np.allclose(from_skeleton_file(path).rest_pose, chain.rest_pose * 2)
    assert [p.name for p in tmp_path.iterdir()] == [f"toy{ext}"]  # no temporary files left


def test_round_trip_of_shipped_human17(tmp_path):
    h = from_skeleton_file(ROBOTS / "human17.toml")
    back = from_skeleton_file(save_skeleton_file(h, tmp_path / "h.yaml"))
    assert back.joints == h.joints and np.allclose(back.rest_pose, h.rest_pose)


def test_units_and_y_up(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("units: cm\nup: y\njoints:\n  - {name: a, rest: [0, 0, 0]}\n  - {name: b, rest: [0, 100, 0]}\n"
                 "bones: [[a, b]]\n")
    chain = from_skeleton_file(f)
    assert np.allclose(chain.rest_pose[1], [0, 0, 1.0])  # 100 cm along +y -> 1 m along +z
    f2 = tmp_path / "t.toml"
    f2.write_text('joints = ["a", "b"]\n[[bones]]\nparent = "a"\nchild = "b"\n')
    assert from_skeleton_file(f2).rest_pose is None


def _line_of(msg: str) -> int | None:
    m = re.search(r"\.(?:toml|yaml):(\d+):", msg)
    return int(m.group(1)) if m else None


GOOD = '''name = "t"
units = "m"

[[joints]]
name = "a"
rest = [0.0, 0.0, 0.0]

[[joints]]
name = "b"
rest = [0.0, 0.0, 1.0]

[[bones]]
parent = "a"
child = "b"
'''


@pytest.mark.parametrize(
    "text, fragment, line",
    [
        (GOOD.replace('name = "t"', "name = "), "TOML syntax error", 1),
        (GOOD.replace('child = "b"', 'child = "bb"'), "unknown joint 'bb'", 14),
        (GOOD.replace('units = "m"', 'units = "furlong"'), "units", 2),
        (GOOD.replace("rest = [0.0, 0.0, 1.0]", "rest = [0.0, 1.0]"), "three finite numbers", 9),
        (GOOD.replace("rest = [0.0, 0.0, 1.0]\n", ""), "no rest position", 9),
        (GOOD + '\n[[bones]]\nparent = "b"\nchild = "a"\n', "cycle", None),
        (GOOD.replace('name = "t"', 'name = "t"\ncolour = "red"'), "unknown key 'colour'", 2),
        (GOOD.replace('name = "b"', 'name = "a"'), "appears twice", 9),
        (GOOD + '\n[[joints]]\nname = "c"\nrest = [1.0, 0.0, 0.0]\n[[bones]]\nparent = "a"\nchild = "c"\n'
         '[[bones]]\nparent = "b"\nchild = "c"\n', "two parents", None),
        ('joints = ["a", "b", "c"]\nbones = [["a", "b"]]\n', "disconnected", None),
    ],
)
def test_bad_toml(tmp_path, text, fragment, line):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(DescriptionError) as exc:
        from_skeleton_file(f)
    msg = str(exc.value)
    assert fragment in msg and str(f) in msg
    if line is not None:
        assert _line_of(msg) == line, msg


def test_bad_yaml_and_files(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("joints: [a, b\nbones: [[a, b]]\n")
    with pytest.raises(DescriptionError, match="YAML syntax error") as exc:
        from_skeleton_file(f)
    assert _line_of(str(exc.value)) == 2
    f.write_text("- just\n- a list\n")
    with pytest.raises(DescriptionError, match="table of keys"):
        from_skeleton_file(f)
    f.write_text("")
    with pytest.raises(DescriptionError, match="empty"):
        from_skeleton_file(f)
    with pytest.raises(DescriptionNotFoundError):
        from_skeleton_file(tmp_path / "missing.toml")
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(DescriptionError, match=".toml, .yaml"):
        from_skeleton_file(tmp_path / "x.json")


# ------------------------------------------------------------------------------------------ fuzzing
def _fuzz_loaders(tmp_path_factory):
    from chainspace import from_asf, load_bvh
    from chainspace.io.datasets import bundled_data_dir

    arm = (Path(__file__).parent / "test_bvh.py").read_text().split('ARM = """', 1)[1].split('"""', 1)[0]
    return {
        "asf": ((bundled_data_dir() / "cmu" / "35.asf").read_text(), from_asf),
        "bvh": (arm, load_bvh),
        "toml": ((ROBOTS / "human17.toml").read_text(), from_skeleton_file),
    }


def test_mutated_descriptions_raise_only_chainspace_errors(tmp_path_factory):
    """Deleted, truncated and corrupted lines in ASF, BVH and TOML files: ChainspaceError or success."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from chainspace import ChainspaceError

    loaders = _fuzz_loaders(tmp_path_factory)
    folder = tmp_path_factory.mktemp("fuzz")
    junk = st.sampled_from(["", "0", "-1", "nan", "1e999", "x", "{", "}", "begin", "end", ":root", "(", "ROOT",
                            "JOINT", "[", "]", '"', "=", "root", "End Site", "MOTION", "Frames: 2", "CHANNELS 9"])
    edit = st.tuples(st.sampled_from(["delete", "replace", "insert", "truncate"]), st.floats(0, 1), junk)

    @settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(kind=st.sampled_from(sorted(loaders)), edits=st.lists(edit, min_size=1, max_size=4))
    def check(kind, edits):
        text, load = loaders[kind]
        lines = text.splitlines()
        for op, where, token in edits:
            i = int(where * len(lines)) if lines else 0
            if op == "delete" and i < len(lines):
                del lines[i]
            elif op == "replace" and i < len(lines):
                lines[i] = token
            elif op == "insert":
                lines.insert(i, token)
            else:
                lines = lines[:i]
        f = folder / f"x.{kind}"
        f.write_text("\n".join(lines) + "\n")
        try:
            load(f)
        except ChainspaceError:
            pass

    check()
