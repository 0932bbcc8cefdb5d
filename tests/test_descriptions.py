"""Shipped descriptions, dispatch by extension, and example-robot-data URDFs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import chainspace.io.descriptions as descriptions
from chainspace.io.descriptions import (
    EXAMPLE_ROBOTS,
    example_robot_urdf,
    list_shipped,
    load_chain,
    shipped,
    shipped_path,
)
from chainspace.errors import ChainspaceError, DescriptionError, DescriptionNotFoundError

SHIPPED = list_shipped()


def test_the_milling_arm_is_shipped():
    assert "milling_arm.urdf" in SHIPPED
    assert SHIPPED == sorted(SHIPPED)
    assert all(Path(n).suffix in {".urdf", ".asf", ".bvh", ".toml", ".yaml", ".yml"} for n in SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_description_loads(name, rng):
    stem = Path(name).stem
    path = shipped_path(stem)
    assert path.is_file() and path.name == name and shipped_path(name) == path
    chain = shipped(stem)
    assert chain.joints == load_chain(stem).joints == load_chain(path).joints == load_chain(str(path)).joints
    # the KCS matrices: for random X, (X C) D = X minus its root
    X = rng.normal(size=(3, chain.n_joints))
    np.testing.assert_allclose(X @ chain.C[:, : chain.n_bones] @ chain.D, X - X[:, [chain.joint_index(chain.root)]], atol=1e-12)
    # shipped chains have a rest pose in metres, Z up: something a camera can be pointed at
    rest = chain.rest_pose
    assert rest is not None and np.isfinite(rest).all()
    extent = np.ptp(rest, axis=0)
    assert 0.2 < extent.max() < 10.0, extent
    assert (chain.bone_lengths(rest)[: chain.n_bones] > 1e-3).all()


def test_shipped_milling_arm_is_the_urdf_chain():
    chain = shipped("milling_arm")
    assert chain.metadata["kind"] == "urdf" and chain.root == "base_link"
    assert Path(chain.metadata["urdf_path"]) == shipped_path("milling_arm").resolve()
    # Z up: the arm stands on the floor
    assert chain.rest_pose[:, 2].min() == pytest.approx(0.0) and chain.rest_pose[:, 2].max() > 0.5


def test_loader_keywords_pass_through():
    chain = load_chain("milling_arm", extra_frames={"probe": ("link_4", (0.5, 0, 0))})
    assert chain.joints[-1] == "probe"


def test_unknown_shipped_name_lists_what_is_there():
    with pytest.raises(DescriptionNotFoundError, match=r"no shipped description 'milling_armm'.*milling_arm\.urdf") as info:
        shipped("milling_armm")
    assert "did you mean 'milling_arm'" in str(info.value).lower()
    with pytest.raises(DescriptionNotFoundError, match="no shipped description"):
        load_chain("human99")


def test_load_chain_dispatches_by_extension(tmp_path, monkeypatch):
    calls = []
    for ext, (module, func) in descriptions._LOADERS.items():
        path = tmp_path / f"x{ext.upper() if ext == '.bvh' else ext}"
        path.write_text("whatever")
        monkeypatch.setattr(descriptions, "_loader", lambda suffix: (lambda p, **kw: calls.append((suffix, p, kw))))
        load_chain(path, flag=1)
        assert calls[-1] == (ext, path, {"flag": 1})


def test_load_chain_rejects_missing_and_unknown_files(tmp_path):
    with pytest.raises(DescriptionNotFoundError, match="nothing.urdf"):
        load_chain(tmp_path / "nothing.urdf")
    with pytest.raises(DescriptionNotFoundError):
        load_chain("robots/nothing.urdf")
    odd = tmp_path / "robot.sdf"
    odd.write_text("<sdf/>")
    with pytest.raises(DescriptionError, match=r"robot\.sdf: unknown description format '\.sdf'"):
        load_chain(odd)
    with pytest.raises(DescriptionError, match="expected a file path"):
        load_chain(42)


def test_bad_urdf_through_load_chain_names_the_file(tmp_path):
    path = tmp_path / "broken.urdf"
    path.write_text('<robot name="r"><link name="a"/><joint name="j" type="fixed">')
    with pytest.raises(DescriptionError, match=r"broken\.urdf:1: malformed XML"):
        load_chain(path)


@pytest.mark.parametrize("name", list(EXAMPLE_ROBOTS))
def test_example_robot_urdfs_exist(name, example_urdf):
    path = example_urdf(name)
    assert path.is_file() and path.suffix == ".urdf"


def test_example_robot_errors(monkeypatch):
    with pytest.raises(ChainspaceError, match=r"unknown example robot 'ur11'.*Did you mean 'ur10'"):
        example_robot_urdf("ur11")
    monkeypatch.setattr(descriptions, "_example_robot_data_root", lambda: None)
    with pytest.raises(ChainspaceError, match="example-robot-data package is not installed"):
        example_robot_urdf("ur10")


def test_example_robots_load_by_name(example_urdf, monkeypatch):
    """`load_chain("ur5")` (and `--chain ur5`, `--urdf ur5`): an example-robot-data robot by its short name,
    after the shipped names; without the package the error says so."""
    path = example_urdf("ur5")
    chain = load_chain("ur5")
    assert chain.metadata["urdf_path"] == str(path) and chain.n_joints >= 7
    with pytest.raises(DescriptionNotFoundError, match=r"no shipped description 'ur55'.*example-robot-data by name: "
                                                       r"ur3, ur5"):
        load_chain("ur55")
    monkeypatch.setattr(descriptions, "_example_robot_data_root", lambda: None)
    with pytest.raises(DescriptionNotFoundError, match="example-robot-data package is not installed"):
        load_chain("ur5")


def test_cli_fit_takes_an_example_robot_by_name(example_urdf, tmp_path):
    """`chainspace fit TRACKS --urdf ur5` resolves the name as load_chain does (it failed with 'no shipped
    description')."""
    from chainspace.cli import _urdf_path

    assert _urdf_path("ur5") == str(example_urdf("ur5"))
    assert _urdf_path("milling_arm").endswith("milling_arm.urdf")
    with pytest.raises(DescriptionNotFoundError):
        _urdf_path("ur55")


def test_shipped_points_example_robots_to_load_chain():
    """`shipped` loads what chainspace ships; an example-robot-data name is pointed to load_chain, and a
    typo gets the names --chain would take (shipped and example robots) as "did you mean"."""
    with pytest.raises(DescriptionNotFoundError, match=r"'ur10' is an example-robot-data robot, not a description "
                                                       r"shipped with chainspace: use chainspace.load_chain\('ur10'\)"):
        shipped("ur10")
    with pytest.raises(DescriptionNotFoundError, match=r"no shipped description 'ur11'.*Did you mean 'ur10'"):
        shipped("ur11")
    with pytest.raises(DescriptionNotFoundError, match=r"no shipped description 'ur11'.*Did you mean 'ur10'"):
        load_chain("ur11")
