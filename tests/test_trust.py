"""Issue 21 (parts 3-6), trustworthy answers: meshes found as ROS finds them, a command line that does
what the API does and speaks its own language, input checks, outputs that say what they hold."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from chainspace.cli import app

runner = CliRunner()

_TWO_LINK = """<?xml version="1.0"?>
<robot name="twolink">
  <link name="base">
    <visual><geometry><mesh filename="{mesh}"/></geometry></visual>
  </link>
  <link name="arm">
    <visual><geometry><mesh filename="package://no_such_package_xyz/meshes/arm.stl"/></geometry></visual>
  </link>
  <link name="tip"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="arm"/><origin xyz="0 0 0.3"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="j2" type="revolute">
    <parent link="arm"/><child link="tip"/><origin xyz="0.4 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
</robot>
"""

_STL = """solid t
facet normal 0 0 1
 outer loop
  vertex 0 0 0
  vertex 0.1 0 0
  vertex 0 0.1 0
 endloop
endfacet
endsolid t
"""


# ---------------------------------------------------------------------------------------- 3. meshes
def _package(tmp_path: Path, mesh: str) -> Path:
    """A ROS package folder my_robot/ (package.xml, urdf/, meshes/base.stl) with the two-link URDF."""
    pkg = tmp_path / "src" / "my_robot"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "meshes").mkdir()
    (pkg / "package.xml").write_text("<package><name>my_robot</name></package>")
    (pkg / "meshes" / "base.stl").write_text(_STL)
    urdf = pkg / "urdf" / "twolink.urdf"
    urdf.write_text(_TWO_LINK.format(mesh=mesh))
    return urdf


def test_resolve_mesh_package_relative_and_file_uris(tmp_path, monkeypatch):
    from chainspace.io.urdf import resolve_mesh

    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    urdf = _package(tmp_path, "package://my_robot/meshes/base.stl")
    want = (urdf.parents[1] / "meshes" / "base.stl").resolve()
    assert resolve_mesh("package://my_robot/meshes/base.stl", urdf).resolve() == want  # the URDF's ancestors
    assert resolve_mesh("../meshes/base.stl", urdf).resolve() == want  # relative to the URDF's folder
    assert resolve_mesh(f"file://{want}", urdf).resolve() == want
    assert resolve_mesh("package://no_such_package_xyz/meshes/arm.stl", urdf) is None
    # a package found through ROS_PACKAGE_PATH only (the URDF elsewhere)
    other = tmp_path / "elsewhere" / "robot.urdf"
    other.parent.mkdir()
    other.write_text("<robot name='x'><link name='a'/></robot>")
    assert resolve_mesh("package://my_robot/meshes/base.stl", other) is None
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "src"))
    assert resolve_mesh("package://my_robot/meshes/base.stl", other).resolve() == want


def test_ur5_meshes_resolve_from_example_robot_data(example_urdf):
    """UR5 names its meshes package://example-robot-data/robots/...: they used to crash the viewer."""
    from chainspace.io.urdf import resolve_mesh, visual_urdf
    from chainspace.view.viewer import _robot_models

    urdf = example_urdf("ur5")
    uri = "package://example-robot-data/robots/ur_description/meshes/ur5/visual/base.dae"
    assert uri in urdf.read_text()
    assert resolve_mesh(uri, urdf).is_file()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every mesh is found: no warning
        xml = visual_urdf(urdf)
        model, visual = _robot_models(urdf)
    assert "package://" not in xml.split("<transmission")[0]
    assert len(visual.geometryObjects) >= 6
    assert all(Path(g.meshPath).is_file() for g in visual.geometryObjects)


def test_missing_mesh_is_drawn_as_a_primitive_with_one_warning(tmp_path, monkeypatch):
    pytest.importorskip("pinocchio")
    from chainspace.view.viewer import write_html

    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    urdf = _package(tmp_path, "package://my_robot/meshes/base.stl")
    fit = _fake_fit(urdf, F=5)
    with pytest.warns(UserWarning, match="no_such_package_xyz/meshes/arm.stl") as caught:
        out = write_html(tmp_path / "v.html", fit=fit)
    assert len([w for w in caught if "not found" in str(w.message)]) == 1
    assert out.stat().st_size > 100_000


def _fake_fit(urdf: Path, F: int = 5):
    from types import SimpleNamespace

    from chainspace.io.urdf import from_urdf, point_positions

    chain = from_urdf(urdf)
    q = np.tile(chain.metadata["q_rest"], (F, 1)) + 0.1 * np.arange(F)[:, None]
    pos = point_positions(chain, q)
    return SimpleNamespace(urdf_path=str(urdf), q=q, positions=pos, chain=chain, rotation=np.eye(3),
                           translation=np.zeros(3), scale=1.0, joint_names=list(chain.metadata["joint_names"]),
                           observable=np.ones(q.shape[1], bool))
