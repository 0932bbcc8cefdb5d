"""Issue 21 (parts 3-6), trustworthy answers: meshes found as ROS finds them, a command line that does
what the API does and speaks its own language, input checks, outputs that say what they hold."""

from __future__ import annotations

import importlib
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


# ---------------------------------------------------------------------------------------- 4. command line
def _one_line_error(result, code: int = 2) -> str:
    assert result.exit_code == code, (result.exit_code, result.output)
    err = result.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in result.output, err
    return err


def test_version():
    from chainspace import __version__

    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.stdout.strip() == f"chainspace {__version__}"


@pytest.mark.parametrize("args", [
    ["reconstruct", "walk.csv", "-c", "human17", "-o", "out", "--fps", "-30"],
    ["reconstruct", "walk.csv", "-c", "human17", "-o", "out", "--fps", "nan"],
    ["reconstruct", "walk.csv", "-c", "human17", "-o", "out", "--image-size", "640", "0"],
    ["view", "result.npz", "--fps", "0"],
    ["fit", "rec.npz", "--fps", "inf"],
])
def test_non_positive_or_non_finite_numbers_exit_2(tmp_path, args):
    result = runner.invoke(app, [a if not a.endswith((".csv", ".npz")) and a != "out" else str(tmp_path / a)
                                 for a in args])
    err = _one_line_error(result)
    assert "must be a finite number > 0" in err and ("--fps" in err or "--image-size" in err)
    assert not (tmp_path / "out").exists()


def _milling_tracks(tmp_path: Path, extra: dict[str, np.ndarray] | None = None, F: int = 6) -> Path:
    from chainspace.io.descriptions import shipped
    from chainspace.io.tracks import save_tracks

    chain = shipped("milling_arm")
    names = list(chain.joints) + list(extra or {})
    pts = np.concatenate([chain.rest_pose] + [np.asarray(v, float)[None] for v in (extra or {}).values()])
    tracks = np.tile(100 * pts[None, :, :2], (F, 1, 1)) + np.arange(F)[:, None, None]
    save_tracks(tmp_path / "tracks.csv", tracks, names)
    return tmp_path / "tracks.csv"


class _Stop(Exception):
    pass


def test_fit_passes_fps_and_extra_frames(tmp_path, monkeypatch):
    """`fit --fps 100 --extra-frame ...`: the chain gets the tracked tool point, the fit the frame rate."""
    from types import SimpleNamespace

    import chainspace.reconstruction.pipeline as pipeline
    import chainspace.robot.fit as robot_fit
    from chainspace.errors import TrackError

    seen = {}

    def fake_reconstruct(W, chain, *args, **kwargs):
        seen["chain"], seen["W"] = chain, W
        return SimpleNamespace(poses=np.zeros((len(W), chain.n_joints, 3)), chain=chain)

    def fake_fit(rec, urdf=None, **kwargs):
        seen["fit"] = kwargs
        raise TrackError("stopped here by the test")

    monkeypatch.setattr(pipeline, "reconstruct", fake_reconstruct)
    monkeypatch.setattr(robot_fit, "fit_joint_angles", fake_fit)
    tracks = _milling_tracks(tmp_path, {"probe": [0.1, 0.2, 0.3]})
    result = runner.invoke(app, ["fit", str(tracks), "--urdf", "milling_arm", "-o", str(tmp_path / "fit"),
                                 "--fps", "100", "--extra-frame", "probe=link_6:0,0,0.25"])
    assert "stopped here by the test" in _one_line_error(result)
    assert seen["fit"]["fps"] == 100.0
    chain = seen["chain"]
    assert "probe" in chain.joints and chain.metadata["extra_frames"]["probe"] == ("link_6", [0.0, 0.0, 0.25])
    assert np.isfinite(seen["W"][:, chain.joint_index("probe")]).all()  # its track was read


@pytest.mark.parametrize("args, expected", [([], ("above", True)), (["--view-from", "below"], ("below", True)),
                                           (["--view-from", "either", "--no-search-ties"], (None, False))])
def test_fit_passes_view_from_and_search_ties(tmp_path, monkeypatch, args, expected):
    """`fit --view-from below|either --no-search-ties`: the API's view_from and search_ties from the shell
    (the search on by default, as in the API)."""
    from types import SimpleNamespace

    import chainspace.reconstruction.pipeline as pipeline
    import chainspace.robot.fit as robot_fit
    from chainspace.errors import TrackError

    seen = {}

    def fake_fit(rec, urdf=None, **kwargs):
        seen.update(kwargs)
        raise TrackError("stopped here by the test")

    monkeypatch.setattr(pipeline, "reconstruct", lambda W, chain, *a, **k: SimpleNamespace(
        poses=np.zeros((len(W), chain.n_joints, 3)), chain=chain))
    monkeypatch.setattr(robot_fit, "fit_joint_angles", fake_fit)
    tracks = _milling_tracks(tmp_path)
    result = runner.invoke(app, ["fit", str(tracks), "--urdf", "milling_arm", "-o", str(tmp_path / "fit")] + args)
    assert "stopped here by the test" in _one_line_error(result)
    assert (seen["view_from"], seen["search_ties"]) == expected


def test_fit_messages_name_the_command_line_options():
    """The fit's advice in the shell's words: --extra-frame, --view-from, not Python names."""
    from chainspace.cli import _for_the_shell

    text = _for_the_shell("to see a joint, track a point that moves with it, off its axis (extra_frames); "
                          "legs or a hanging limb, where the camera-side rule (view_from) does not apply; "
                          "differ there by 5 deg RMS (fit.alternatives); uncertain: joint_a4 (6.7 deg): the reported "
                          "standard deviation (RMS over the frames, fit.q_std) is more than 2 degrees")
    assert "--extra-frame" in text and "--view-from" in text and "joint_angles.npz" in text
    assert "extra_frames" not in text and "(view_from)" not in text and "fit.alternatives" not in text
    assert "fit.q_std" not in text and "q_std in joint_angles.npz" in text


@pytest.mark.parametrize("spec", ["probe", "probe=link_6", "probe=link_6:0,0", "=link_6:0,0,1",
                                  "probe=link_6:0,x,1", "probe=nolink:0,0,1"])
def test_bad_extra_frame_exits_2(tmp_path, spec):
    tracks = _milling_tracks(tmp_path)
    result = runner.invoke(app, ["reconstruct", str(tracks), "-c", "milling_arm", "-o", str(tmp_path / "o"),
                                 "--extra-frame", spec])
    err = _one_line_error(result)
    assert ("extra frame" in err or "--extra-frame" in err) and ("probe" in err or "link_6" in err)


def test_extra_frame_needs_a_urdf_chain(tmp_path):
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "w.csv"), "-c", "human17", "-o",
                                 str(tmp_path / "o"), "--extra-frame", "tip=lhand:0,0,0.1"])
    assert "--extra-frame needs a URDF chain" in _one_line_error(result)


def test_link_tracks_part_of_a_chain_from_the_shell(tmp_path, monkeypatch):
    """Tracks of some links only: the error names --link, and `--link NAME ...` keeps those points, in that
    order, each hanging from its nearest kept ancestor (from_urdf(links=...); a skeleton's chain.subset)."""
    from types import SimpleNamespace

    import chainspace.reconstruction.pipeline as pipeline
    import chainspace.robot.fit as robot_fit
    from chainspace.errors import TrackError
    from chainspace.io.tracks import load_tracks, save_tracks

    full = _milling_tracks(tmp_path)
    W, _, names = load_tracks(full)
    kept = ["base_link", "link_2", "link_3", "link_5", "link_6", "tool_tip"]
    save_tracks(tmp_path / "part.csv", W[:, [names.index(n) for n in kept]], kept)
    missing = runner.invoke(app, ["reconstruct", str(tmp_path / "part.csv"), "-c", "milling_arm", "-o",
                                  str(tmp_path / "o")])
    assert "--link" in _one_line_error(missing) and "chain.subset" not in _one_line_error(missing)
    seen = {}

    def fake_fit(rec, urdf=None, **kwargs):
        raise TrackError("stopped here by the test")

    monkeypatch.setattr(pipeline, "reconstruct", lambda W, chain, *a, **k: seen.update(chain=chain, W=W) or
                        SimpleNamespace(poses=np.zeros((len(W), chain.n_joints, 3)), chain=chain))
    monkeypatch.setattr(robot_fit, "fit_joint_angles", fake_fit)
    result = runner.invoke(app, ["fit", str(tmp_path / "part.csv"), "--urdf", "milling_arm", "-o",
                                 str(tmp_path / "fit")] + [a for n in kept for a in ("--link", n)])
    assert "stopped here by the test" in _one_line_error(result)
    assert list(seen["chain"].joints) == kept and ("link_3", "link_5") in seen["chain"].bones
    np.testing.assert_allclose(seen["W"], W[:, [names.index(n) for n in kept]])
    # a skeleton's joints alike; a name the chain lacks is said
    human = runner.invoke(app, ["reconstruct", str(tmp_path / "part.csv"), "-c", "human17", "-o",
                                str(tmp_path / "h"), "--link", "pelvis", "--link", "nosuchjoint"])
    assert "nosuchjoint" in _one_line_error(human)
    with_markers = runner.invoke(app, ["fit", str(tmp_path / "part.csv"), "--urdf", "milling_arm", "-o",
                                       str(tmp_path / "m"), "--markers", "milling_arm", "--link", "link_2"])
    assert "--link and --markers" in _one_line_error(with_markers)


def test_unexpected_errors_exit_3_not_1(tmp_path, monkeypatch):
    """1 means "not converged or failed validation"; a bug must not pass for that."""
    import chainspace.reconstruction.pipeline as pipeline

    def boom(*args, **kwargs):
        raise RuntimeError("something\nbroke")

    monkeypatch.setattr(pipeline, "reconstruct", boom)
    tracks = _milling_tracks(tmp_path)
    result = runner.invoke(app, ["reconstruct", str(tracks), "-c", "milling_arm", "-o", str(tmp_path / "o")])
    err = _one_line_error(result, 3)
    assert "internal error: RuntimeError: something broke" in err


def test_messages_speak_the_command_line(tmp_path):
    from chainspace.cli import _for_the_shell

    out = tmp_path / "o"
    out.mkdir()
    (out / "reconstruction.npz").write_bytes(b"x")
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "w.csv"), "-c", "human17", "-o", str(out)])
    err = _one_line_error(result)
    assert "--overwrite" in err and "overwrite=True" not in err
    assert "chain.subset" not in _for_the_shell("joint 'a' is never seen; drop it with chain.subset(...) or "
                                                "provide its track")
    assert "--urdf" in _for_the_shell("fit_joint_angles needs the robot's URDF: pass urdf=PATH or a chain made "
                                      "by chainspace.from_urdf")


def test_bench_without_its_data_exits_2(monkeypatch):
    benchmark = importlib.import_module("chainspace.bench.reconstruction")
    monkeypatch.setattr(benchmark, "run_benchmark", lambda *, quick, progress: [])
    result = runner.invoke(app, ["bench", "--suite", "reconstruction", "--quick"])
    assert result.exit_code == 2 and "none of its data" in result.stderr
    assert "|" not in result.stdout  # no empty table


# ---------------------------------------------------------------------------------------- 5. input checks
def test_csv_cut_short_at_a_line_boundary_names_file_and_frame(tmp_path):
    from chainspace.errors import TrackError
    from chainspace.io.tracks import load_tracks, save_tracks

    names = ["a", "b", "c", "d"]
    tracks = np.arange(5 * 4 * 2, dtype=float).reshape(5, 4, 2)
    save_tracks(tmp_path / "t.csv", tracks, names)
    lines = (tmp_path / "t.csv").read_text().splitlines(keepends=True)
    (tmp_path / "cut.csv").write_text("".join(lines[:-2]))  # frame 4 keeps a and b only
    with pytest.raises(TrackError, match=r"cut\.csv:\d+: the last frame \(4\) has rows for only 2 of the 4 "
                                         r"joints \(no row for c, d\)"):
        load_tracks(tmp_path / "cut.csv")
    # the whole file, and a joint missing in every frame (a tracker that never saw it), are fine
    P, _, _ = load_tracks(tmp_path / "t.csv")
    assert P.shape == (5, 4, 2)
    (tmp_path / "three.csv").write_text("".join(ln for ln in lines if ",d," not in ln))
    assert load_tracks(tmp_path / "three.csv")[0].shape == (5, 3, 2)
    # through the command line: exit 2, one line naming the file
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "cut.csv"), "-c", "human17", "-o",
                                 str(tmp_path / "o")])
    assert "cut.csv" in _one_line_error(result) and "frame (4)" in result.stderr


@pytest.mark.parametrize("suffix", [".npy", ".npz"])
def test_nameless_array_of_the_wrong_joint_count_names_both_counts(tmp_path, suffix):
    from chainspace.errors import TrackError
    from chainspace.io.datasets import human17
    from chainspace.io.tracks import load_tracks

    chain = human17()
    bad = np.zeros((10, 15, 2))
    path = tmp_path / f"t{suffix}"
    np.save(path, bad) if suffix == ".npy" else np.savez(path, tracks=bad)
    with pytest.raises(TrackError, match=f"15 joints .* has {chain.n_joints}"):
        load_tracks(path, chain=chain)
    # the right count without names: taken in the chain's order
    good = np.random.default_rng(0).normal(size=(10, chain.n_joints, 2))
    np.save(path, good) if suffix == ".npy" else np.savez(path, tracks=good)
    P, _, names = load_tracks(path, chain=chain)
    np.testing.assert_allclose(P, good)
    assert names == list(chain.joints)


# ---------------------------------------------------------------------------------------- 6. clear outputs
def test_relative_joints_are_plotted_relative_to_frame_0(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from chainspace.view import plots

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path, overwrite: figures.append(fig) or Path(path))
    F = 30
    truth = np.stack([0.45 + 0.3 * np.sin(np.arange(F) / 5), 0.2 * np.cos(np.arange(F) / 7)], axis=1)
    q = truth.copy()
    q[:, 0] -= truth[0, 0]  # the first joint is seen only relative to frame 0: it starts at 0
    fit = SimpleNamespace(q=q, joint_names=["a1", "a2"], observable=np.array([False, True]),
                          relative=np.array([True, False]))
    plots.plot_joint_angles(fit, truth, tmp_path / "q.png")
    ax1, ax2 = [ax for ax in figures[0].axes if ax.get_visible()][:2]
    assert "relative to frame 0" in ax1.get_ylabel() and "relative to frame 0" not in ax2.get_ylabel()
    labels = [ln.get_label() for ln in ax1.get_lines()]
    assert labels == ["truth (relative to frame 0)", "fitted (relative to frame 0)"]
    t_line, f_line = ax1.get_lines()
    np.testing.assert_allclose(t_line.get_ydata(), f_line.get_ydata(), atol=1e-9)  # the curves agree
    assert t_line.get_ydata()[0] == 0.0
    np.testing.assert_allclose(ax2.get_lines()[0].get_ydata(), np.degrees(truth[:, 1]))  # absolute as before
    assert "NOT OBSERVABLE" not in ax1.get_ylabel() + ax2.get_ylabel()
    # a joint not seen at all (held where the fit started it) is labelled so, not drawn as a fitted 0
    figures.clear()
    held = SimpleNamespace(**{**fit.__dict__, "observable": np.array([True, False]), "relative": np.array([False, False])})
    plots.plot_joint_angles(held, truth, tmp_path / "q2.png")
    ax1, ax2 = [ax for ax in figures[0].axes if ax.get_visible()][:2]
    assert "NOT OBSERVABLE" in ax2.get_ylabel() and "NOT OBSERVABLE" not in ax1.get_ylabel()
    assert "fitted (not observable: held)" in [ln.get_label() for ln in ax2.get_lines()]


def test_bone_lengths_robot_from_urdf_apart_from_scale_free_reconstruction():
    from types import SimpleNamespace

    from chainspace.chain import KinematicChain
    from chainspace.robot.validation import BONES_NOTE, ValidationReport, _bone_errors

    chain = KinematicChain(["a", "b", "c"], [("a", "b"), ("b", "c")], name="arm")
    robot = SimpleNamespace(q_rest=np.zeros(1), positions=lambda q: np.array([[[0, 0, 0], [1, 0, 0], [1, 3, 0]]],
                                                                               dtype=float))
    poses = np.tile(np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0]], dtype=float), (4, 1, 1))  # 2 and 2: scale-free
    bones = _bone_errors(robot, SimpleNamespace(chain=chain, input_poses=poses, scale=1.0))
    assert [b["urdf_share_pct"] for b in bones] == pytest.approx([25.0, 75.0])
    assert [b["reconstruction_share_pct"] for b in bones] == pytest.approx([50.0, 50.0])
    assert [b["share_error_pct"] for b in bones] == pytest.approx([100.0, -100 / 3])
    report = ValidationReport(joints=[], bones=bones, reprojection_rms_px=None, error_3d_mm=None,
                              error_3d_pct_reach=None, reach_mm=4000.0, thresholds={}, checks={})
    table = report.table()
    assert BONES_NOTE in table and "URDF (metres" in BONES_NOTE and "fixes no scale" in BONES_NOTE
    assert "| bone | fitted robot (URDF) m | robot share % | reconstruction share % (scale-free) |" in table
    assert "| a-b | 1.0000 | 25.0 | 50.0 | +100.0 |" in table
    assert "not compared" not in table
    # a bone whose ends lie on links that move against each other (markers on two links) has no one length
    chain.metadata["variable_bones"] = [("b", "c")]
    bones = _bone_errors(robot, SimpleNamespace(chain=chain, input_poses=poses, scale=1.0))
    table = ValidationReport(joints=[], bones=bones, reprojection_rms_px=None, error_3d_mm=None,
                             error_3d_pct_reach=None, reach_mm=4000.0, thresholds={}, checks={}).table()
    assert "| b-c | 3.0000 | - | - | - |" in table
    assert "- not compared (its ends lie on links that move against each other, so no one length): b-c" in table
    assert report.to_dict()["bones_note"] == BONES_NOTE


def test_fit_summary_mm_fields_hold_millimetres_on_the_robot(tmp_path):
    from types import SimpleNamespace

    from chainspace.chain import KinematicChain
    from chainspace.io.results import save_results

    F = 4
    chain = KinematicChain(["a", "b"], [("a", "b")], name="arm").with_rest_pose(np.eye(3)[:2])
    fit = SimpleNamespace(q=np.zeros((F, 2)), joint_names=["j1", "j2"], observable=np.array([False, True]),
                          relative=np.array([True, False]), positions=np.zeros((F, 2, 3)),
                          residual_3d=np.full(F, 0.004), residual_px=None, converged=np.ones(F, bool),
                          scale=2.0, rotation=np.eye(3), translation=np.zeros(3), cameras=None,
                          translations_2d=None, chain=chain, urdf_path="arm.urdf", message="ok", n_iter=1)
    save_results(fit, tmp_path)
    summary = json.loads((tmp_path / "joint_angles.json").read_text())
    # 0.004 reconstruction units at a scale of 2 (reconstruction units per robot metre): 2 mm on the robot
    assert summary["residual_3d_mm"]["mean"] == pytest.approx(2.0)
    assert summary["residual_3d_reconstruction_units"]["mean"] == pytest.approx(0.004)
    assert summary["relative_to_frame_0"] == ["j1"]


def test_progress_lines_for_long_stages_are_plain_and_timed():
    import time

    from chainspace.demo import _Ticker

    lines = []
    with _Ticker(lines.append, "fitting 300 frames", every=0.05, expected_s=100.0):
        time.sleep(0.18)
    assert len(lines) >= 3
    assert all(ln.startswith("      ... fitting 300 frames: ") for ln in lines)
    assert "s elapsed, about" in lines[0] and "s left" in lines[0]
    assert lines[-1].startswith("      ... fitting 300 frames: done in ")
    with _Ticker(False, "quiet", every=0.01):  # progress=False: no thread, no output
        time.sleep(0.03)
    lines.clear()
    with _Ticker(lines.append, "rendering 300 frames", every=0.05) as ticker:  # a stage that counts
        ticker.count(60, 300)
        time.sleep(0.12)
    assert lines[0].startswith("      ... rendering 300 frames: 60/300, 0 s elapsed, about 0 s left"), lines


def test_piped_progress_lines_give_counts_and_time_left(capsys, monkeypatch):
    """A stage's progress on a pipe: plain lines with the count, the time elapsed and the time left."""
    from chainspace import progress

    clock = iter([0.0, 10.0, 40.0])
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    with progress.progress_reporter(True, 4, "tracking") as report:
        report(1)
        report(4)
    err = capsys.readouterr().err.splitlines()
    assert err == ["tracking: 1/4 frames, 10 s elapsed, about 30 s left", "tracking: 4/4 frames, 40 s elapsed"]


def test_track_format_advice_names_the_option(tmp_path):
    (tmp_path / "walk.txt").write_text("x")
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "walk.txt"), "-c", "human17", "-o",
                                 str(tmp_path / "o")])
    err = _one_line_error(result)
    assert "give --format, one of" in err and "format=" not in err


def test_view_of_a_robot_with_a_missing_mesh_warns_and_writes(tmp_path, monkeypatch):
    """`chainspace view` used to die with 'Mesh package://... could not be found' (exit 1, "not
    converged"); now it draws a primitive, warns on one line and exits 0."""
    from chainspace.io.results import save_results

    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    urdf = _package(tmp_path, "package://my_robot/meshes/base.stl")
    fit = _fake_fit(urdf, F=5)
    F = len(fit.q)
    fit.__dict__.update(residual_3d=np.zeros(F), residual_px=None, converged=np.ones(F, bool), cameras=None,
                        translations_2d=None, message="ok", n_iter=1)
    save_results(fit, tmp_path / "fit")
    result = runner.invoke(app, ["view", str(tmp_path / "fit" / "joint_angles.npz"), "--html",
                                 str(tmp_path / "v.html")])
    assert result.exit_code == 0, result.output
    warning = [ln for ln in result.stderr.splitlines() if "warning" in ln]
    assert len(warning) == 1 and "no_such_package_xyz/meshes/arm.stl" in warning[0]
    assert (tmp_path / "v.html").stat().st_size > 100_000


@pytest.mark.parametrize("command", [["reconstruct", "w.csv", "-c", "human17", "-o", "o"], ["demo", "-o", "o"]])
def test_negative_seed_exits_2(tmp_path, command):
    args = [str(tmp_path / a) if a in ("w.csv", "o") else a for a in command] + ["--seed", "-1"]
    assert "--seed must be an integer >= 0" in _one_line_error(runner.invoke(app, args))
    assert not (tmp_path / "o").exists()


def test_validation_table_explains_relative_joints():
    from chainspace.robot.validation import ValidationReport

    joints = [{"name": "a1", "status": "relative to frame 0", "judged": True, "rms": 0.2, "max": 0.4,
               "unit": "deg"},
              {"name": "a2", "status": "observable", "judged": True, "rms": 0.1, "max": 0.3, "unit": "deg"}]
    table = ValidationReport(joints=joints, bones=[], reprojection_rms_px=None, error_3d_mm=None,
                             error_3d_pct_reach=None, reach_mm=1000.0, thresholds={}, checks={}).table()
    assert "| a1 | relative to frame 0 |" in table
    assert "- a1: seen only relative to frame 0" in table and "change since frame 0" in table


@pytest.mark.parametrize("spec", ["tracks_misfit", "joint_rms=1", "joint_rms_deg=0", "joint_rms_deg=-1",
                                  "joint_rms_deg=nan", "joint_rms_deg=abc"])
def test_bad_validate_threshold_exits_2(tmp_path, spec):
    result = runner.invoke(app, ["validate", str(tmp_path / "joint_angles.npz"), "--threshold", spec])
    assert result.exit_code == 2 and "--threshold" in result.output and spec in result.output


def test_validate_threshold_reaches_the_report(tmp_path, monkeypatch):
    """`validate --threshold joint_rms_deg=5 --threshold tracks_misfit=inf`: validate's thresholds."""
    import chainspace.io.results as results
    import chainspace.robot.validation as validation
    from types import SimpleNamespace

    seen = {}

    def fake_validate(fit, truth_q=None, *, thresholds=None, truth_positions=None):
        seen.update(thresholds)
        return SimpleNamespace(table=lambda: "table", passed=True)

    monkeypatch.setattr(results, "load_results", lambda path: SimpleNamespace(q=np.zeros((3, 6)), joint_names=[]))
    monkeypatch.setattr(validation, "validate", fake_validate)
    result = runner.invoke(app, ["validate", str(tmp_path / "f.npz"), "--threshold", "joint_rms_deg=5",
                                 "--threshold", "tracks_misfit=inf"])
    assert result.exit_code == 0, result.output
    assert seen == {"joint_rms_deg": 5.0, "tracks_misfit": float("inf")}
