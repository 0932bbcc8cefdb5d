"""The chainspace command through typer's test runner: outputs, exit codes, messages."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from chainspace.cli import app

runner = CliRunner()


def _run(*args: str):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """Synthetic 2D tracks (CSV) of a bundled CMU walk, seen by one orbiting camera."""
    datasets = importlib.import_module("chainspace.io.datasets")
    synthetic = importlib.import_module("chainspace.synthetic.views")
    from chainspace.io.tracks import save_tracks

    d = tmp_path_factory.mktemp("walk")
    chain, poses = datasets.human17(), datasets.cmu_walk(35, 1)[:40]
    tracks = synthetic.observe(poses, synthetic.orbit_cameras(len(poses), seed=1, scale=300.0), noise_px=0.5,
                               seed=2)
    save_tracks(d / "walk.csv", tracks, chain.joints)
    np.save(d / "truth.npy", poses)
    return d


@pytest.mark.parametrize("command", ["chains", "reconstruct", "fit", "validate", "view", "bench", "demo"])
def test_help_has_an_example(command):
    result = _run(command, "--help")
    assert result.exit_code == 0
    assert f"Example: chainspace {command}" in result.output


def test_chains_lists_shipped_descriptions():
    result = _run("chains")
    assert result.exit_code == 0
    line = next(ln for ln in result.output.splitlines() if ln.startswith("human17 "))
    assert "17 joints" in line and "16 bones" in line


def test_reconstruct_writes_results_and_refuses_to_overwrite(walk, tmp_path):
    out = tmp_path / "res"
    result = _run("reconstruct", walk / "walk.csv", "--chain", "human17", "--out", out, "--truth",
                  walk / "truth.npy", "--bvh", tmp_path / "walk.bvh", "--html", tmp_path / "walk.html")
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "reconstruction.json").read_text())
    assert summary["converged"] is True and summary["n_frames"] == 40
    assert summary["errors"]["error_3d_by_stage_m"]["refine"] < 0.1  # metres: the truth was given
    header = (out / "reconstruction.csv").read_text().splitlines()[0]
    assert header == "frame,joint,x,y,z"
    bvh = (tmp_path / "walk.bvh").read_text()
    assert bvh.startswith("HIERARCHY") and "Frames: 40" in bvh
    assert (tmp_path / "walk.html").stat().st_size > 100_000
    before = (out / "reconstruction.npz").read_bytes()
    again = runner.invoke(app, ["reconstruct", str(walk / "walk.csv"), "-c", "human17", "-o", str(out)])
    assert again.exit_code == 2
    assert "already exists" in again.stderr and "--overwrite" in again.stderr
    assert (out / "reconstruction.npz").read_bytes() == before
    forced = _run("reconstruct", walk / "walk.csv", "-c", "human17", "-o", out, "--overwrite", "--method", "kcs")
    summary = json.loads((out / "reconstruction.json").read_text())
    assert summary["method"] == "kcs"
    assert forced.exit_code == (0 if summary["converged"] else 1)  # 1: the run worked but did not converge
    if not summary["converged"]:
        assert "did not converge" in forced.stderr
    # the saved result opens in the viewer
    view = _run("view", out / "reconstruction.npz", "--html", tmp_path / "view.html")
    assert view.exit_code == 0 and (tmp_path / "view.html").exists()


@pytest.mark.parametrize("content,message", [
    ("frame,joint,x,y\n0,pelvis,1,2\n0,left_hip,oops,2\n", "walk.csv:3: malformed"),
    ("frame,joint,u,v\n0,pelvis,1,2\n", "walk.csv:1: wrong columns"),
    ("", "empty"),
    ("frame,joint,x,y\n0,wing,1,2\n", "no joint name of the tracks matches"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, content, message):
    (tmp_path / "walk.csv").write_text(content)
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "walk.csv"), "-c", "human17", "-o",
                                 str(tmp_path / "out")])
    assert result.exit_code == 2
    assert message in result.stderr
    assert "Traceback" not in result.output and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_usage_errors_exit_2(tmp_path):
    assert runner.invoke(app, ["reconstruct", str(tmp_path / "x.csv")]).exit_code == 2  # no --chain
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "x.csv"), "-c", "human17", "-o", str(tmp_path)])
    assert result.exit_code == 2 and "no such track file" in result.stderr
    result = runner.invoke(app, ["reconstruct", str(tmp_path / "x.csv"), "-c", "nobody", "-o", str(tmp_path)])
    assert result.exit_code == 2 and "no shipped description 'nobody'" in result.stderr
    result = runner.invoke(app, ["view", str(tmp_path / "missing.npz"), "--html", str(tmp_path / "v.html")])
    assert result.exit_code == 2 and "no such result file" in result.stderr


def test_bench_dispatches_to_the_suite(monkeypatch):
    benchmark = importlib.import_module("chainspace.bench.reconstruction")
    calls = []

    def fake_run(*, quick, progress):
        calls.append(quick)
        progress("walk35 at 0 px: done")
        return ["row"]

    monkeypatch.setattr(benchmark, "run_benchmark", fake_run)
    monkeypatch.setattr(benchmark, "format_table", lambda rows: f"| table of {len(rows)} row |")
    result = runner.invoke(app, ["bench", "--suite", "reconstruction", "--quick"])
    assert result.exit_code == 0 and calls == [True]
    assert "| table of 1 row |" in result.stdout


def test_bench_unknown_suite_is_a_usage_error():
    result = runner.invoke(app, ["bench", "--suite", "nonsense"])
    assert result.exit_code == 2


def _fake_module(monkeypatch, name, **attrs):
    import sys
    import types

    mod = types.ModuleType(f"chainspace.{name}")
    mod.__dict__.update(attrs)
    monkeypatch.setitem(sys.modules, f"chainspace.{name}", mod)
    return mod


def _saved_fit(tmp_path, F=20):
    from types import SimpleNamespace

    from chainspace.chain import KinematicChain
    from chainspace.io.results import save_results

    chain = KinematicChain(["base", "tip"], [("base", "tip")], name="arm")
    fit = SimpleNamespace(q=np.zeros((F, 2)), joint_names=["j1", "j2"], observable=np.ones(2, bool),
                          positions=np.zeros((F, 2, 3)), residual_3d=np.zeros(F), residual_px=None,
                          converged=np.ones(F, bool), scale=1.0, rotation=np.eye(3), translation=np.zeros(3),
                          cameras=None, translations_2d=None, chain=chain, urdf_path="arm.urdf", message="ok",
                          n_iter=1)
    save_results(fit, tmp_path / "fit")
    return tmp_path / "fit" / "joint_angles.npz"


@pytest.mark.parametrize("passed", [True, False])
def test_validate_exit_code_follows_the_report(monkeypatch, tmp_path, passed):
    seen = {}

    class Report:
        def __init__(self, fit, truth_q, thresholds=None):
            seen["q"], seen["truth"] = fit.q, truth_q
            self.passed = passed

        def table(self):
            return "| joint | rms deg |\n| j1 | 0.1 |"

        def to_dict(self):
            return {"passed": self.passed, "joints": [{"name": "j1", "rms_deg": 0.1, "max_deg": 0.2}]}

    _fake_module(monkeypatch, "robot.validation", validate=Report)
    fit_file = _saved_fit(tmp_path)
    np.save(tmp_path / "truth.npy", np.full((20, 2), 0.5))
    result = runner.invoke(app, ["validate", str(fit_file), "--truth", str(tmp_path / "truth.npy"), "--out",
                                 str(tmp_path / "val")])
    assert result.exit_code == (0 if passed else 1)
    assert "| j1 | 0.1 |" in result.stdout
    np.testing.assert_allclose(seen["truth"], 0.5)
    assert json.loads((tmp_path / "val" / "validation.json").read_text())["passed"] is passed
    assert (tmp_path / "val" / "validation.md").read_text().startswith("| joint |")
    if not passed:
        assert "validation failed" in result.stderr
    # a CSV is read by column name (units in parentheses ignored), whatever the column order
    rows = "\n".join(f"{k},{k / 30:.3f},{0.2},{0.1}" for k in range(20))
    (tmp_path / "truth.csv").write_text("frame,time_s,j2 (rad),j1 (rad)\n" + rows + "\n")
    runner.invoke(app, ["validate", str(fit_file), "--truth", str(tmp_path / "truth.csv")])
    np.testing.assert_allclose(seen["truth"], np.tile([0.1, 0.2], (20, 1)))
    # truth of the wrong shape is bad input
    np.save(tmp_path / "bad.npy", np.zeros((20, 3)))
    bad = runner.invoke(app, ["validate", str(fit_file), "--truth", str(tmp_path / "bad.npy")])
    assert bad.exit_code == 2 and "expected (frames, 2)" in bad.stderr


def test_demo_adds_viewer_and_plots(monkeypatch, tmp_path):
    """`chainspace demo` runs chainspace.demo.run_demo, then writes the viewer and plots it returns."""
    pytest.importorskip("pinocchio")
    descriptions = importlib.import_module("chainspace.io.descriptions")
    fit_mod = importlib.import_module("chainspace.robot.fit")
    from types import SimpleNamespace

    chain = descriptions.shipped("milling_arm")
    robot = fit_mod.RobotKinematics(chain.metadata["urdf_path"], chain)
    q = robot.clip(robot.q_rest + 0.2 * np.sin(np.arange(30)[:, None] / 10 + np.arange(robot.nq)))
    fit = SimpleNamespace(urdf_path=chain.metadata["urdf_path"], q=q, positions=robot.positions(q), chain=chain,
                          rotation=np.eye(3), translation=np.zeros(3), scale=1.0, joint_names=list("abcdef"),
                          observable=np.ones(robot.nq, bool))
    report = SimpleNamespace(passed=False, to_dict=lambda: {"joints": [{"name": "a", "rms_deg": 1.0, "max_deg": 2.0}]})
    calls = []

    def run_demo(out, *, overwrite=False, progress=True, seed=0, n_frames=300):
        calls.append((str(out), overwrite, seed, n_frames))
        return {"fit": fit, "truth_q": q + 0.01, "report": report, "passed": False, "table": "| a | 1.0 |"}

    _fake_module(monkeypatch, "demo", run_demo=run_demo)
    result = runner.invoke(app, ["demo", "--out", str(tmp_path / "d"), "--seed", "3", "--frames", "30"])
    assert calls == [(str(tmp_path / "d"), False, 3, 30)]
    assert result.exit_code == 1 and "validation failed" in result.stderr  # the report did not pass
    assert "| a | 1.0 |" in result.stdout
    for name in ("viewer.html", "joint_angles.png", "joint_errors.png"):
        assert (tmp_path / "d" / name).stat().st_size > 1000
    again = runner.invoke(app, ["demo", "--out", str(tmp_path / "d")])
    assert again.exit_code == 2 and "--overwrite" in again.stderr
    assert runner.invoke(app, ["demo", "--out", str(tmp_path / "d"), "--overwrite"]).exit_code == 1


def _inputs(d):
    """Stand-in input files: the commands must refuse before they read them."""
    for name in ("arm_tracks.csv", "arm.mp4", "keyframes.json", "fit.npz", "truth.npy", "summary.csv", "report.md"):
        (d / name).write_text("an input\n")
    return d


@pytest.mark.parametrize("args,option,role,name", [
    (["reconstruct", "arm_tracks.csv", "--chain", "milling_arm", "--out", "arm_tracks.csv"], "--out",
     "tracks file", "arm_tracks.csv"),
    (["reconstruct", "arm_tracks.csv", "--chain", "milling_arm", "--out", "arm_tracks.npz"], "--out",
     "tracks file", "arm_tracks.csv"),  # a stem: .npz, .csv and .json are written
    (["reconstruct", "arm_tracks.csv", "--chain", "milling_arm", "--out", "r", "--bvh", "truth.npy",
      "--truth", "truth.npy"], "--bvh", "truth file", "truth.npy"),
    (["fit", "fit.npz", "--out", "fit.csv"], "--out", "reconstruction or tracks file", "fit.npz"),
    (["validate", "report.md", "--out", "report.csv"], "--out", "fit", "report.md"),  # report.json, .md
    (["view", "fit.npz", "--html", "fit.npz"], "--html", "result", "fit.npz"),
    (["overlay", "arm.mp4", "fit.npz", "--out", "arm.mp4"], "--out", "video", "arm.mp4"),
    (["track", "arm.mp4", "--points", "keyframes.json", "--chain", "milling_arm", "--out", "keyframes.json"],
     "--out", "key-frame file", "keyframes.json"),
    (["pick", "arm.mp4", "--out", "arm.mp4"], "--out", "video", "arm.mp4"),
    (["markers", "arm.mp4", "--map", "milling_arm", "--out", "arm.mp4"], "--out", "video", "arm.mp4"),
])
def test_no_command_replaces_its_own_input(tmp_path, monkeypatch, args, option, role, name):
    monkeypatch.chdir(_inputs(tmp_path))
    for extra in ([], ["--overwrite"]):
        result = runner.invoke(app, args + extra)
        assert result.exit_code == 2, result.output
        assert f"{option} " in result.stderr and f"would replace the input {role} {name}" in result.stderr
        assert "use --overwrite" not in result.stderr  # never offered for an input
    assert (tmp_path / name).read_text() == "an input\n"


def test_an_input_reached_through_a_link_or_a_folder_is_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(_inputs(tmp_path))
    (tmp_path / "link.csv").symlink_to(tmp_path / "arm_tracks.csv")
    result = runner.invoke(app, ["reconstruct", "link.csv", "-c", "milling_arm", "-o", "arm_tracks.npz",
                                 "--overwrite"])
    assert result.exit_code == 2 and "the input tracks file link.csv" in result.stderr
    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "reconstruction.csv").write_text("an input\n")
    result = runner.invoke(app, ["reconstruct", "res/reconstruction.csv", "-c", "milling_arm", "-o", "res",
                                 "--overwrite"])
    assert result.exit_code == 2
    assert "--out res would replace the input tracks file res/reconstruction.csv" in result.stderr


def test_batch_does_not_write_its_summary_over_the_manifest(tmp_path):
    (tmp_path / "summary.csv").write_text("name,tracks,chain\n")
    result = runner.invoke(app, ["batch", str(tmp_path / "summary.csv"), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "would replace the input manifest" in result.stderr


def test_reconstruct_checks_the_files_a_stem_out_writes_before_the_work(tmp_path, monkeypatch):
    """--out res/walk.npz writes res/walk.npz, .csv and .json: an existing one is refused at once."""
    monkeypatch.chdir(_inputs(tmp_path))
    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "walk.csv").write_text("an earlier result\n")
    result = runner.invoke(app, ["reconstruct", "arm_tracks.csv", "-c", "no_such_chain", "-o", "res/walk.npz"])
    assert result.exit_code == 2
    assert "res/walk.csv already exists; use --overwrite to replace it" in result.stderr


def _arm_tracks(path, names=None):
    from chainspace.io.descriptions import load_chain
    from chainspace.io.tracks import save_tracks

    joints = load_chain("milling_arm").joints
    tracks = np.random.default_rng(0).uniform(100, 500, (12, len(joints), 2))
    save_tracks(path, tracks, names or joints)
    return path


def test_link_messages_speak_of_link(tmp_path):
    """Tracked links that --link leaves out are unselected (no --extra-frame advice); an unknown --link
    name is one plain sentence with the likely meant links."""
    tracks = _arm_tracks(tmp_path / "t.csv")
    result = _run("reconstruct", tracks, "-c", "milling_arm", "--link", "base_link", "--link", "link_2",
                  "-o", tmp_path / "r")
    assert ("7 tracked points not selected for the chain milling_arm by --link, left out: link_1, link_3"
            in result.stderr)
    assert "--extra-frame" not in result.stderr
    result = _run("reconstruct", tracks, "-c", "milling_arm", "--link", "lnk_2", "-o", tmp_path / "r")
    assert result.exit_code == 2
    assert "milling_arm.urdf: unknown link 'lnk_2' in --link (did you mean 'link_2'" in result.stderr


def test_a_misspelt_track_name_gets_a_hint(tmp_path):
    from chainspace.io.descriptions import load_chain

    names = [n if n != "link_2" else "lnk_2" for n in load_chain("milling_arm").joints]
    result = _run("reconstruct", _arm_tracks(tmp_path / "t.csv", names), "-c", "milling_arm", "-o", tmp_path / "r")
    assert result.exit_code == 2
    assert "left out: lnk_2 (did you mean 'link_2'? a point on a robot link" in result.stderr
    assert "joint 'link_2' is never seen" in result.stderr


def test_view_of_a_tracks_file_says_it_is_no_result(tmp_path):
    result = _run("view", _arm_tracks(tmp_path / "t.csv"), "--html", tmp_path / "v.html")
    assert result.exit_code == 2
    assert "t.csv: not a chainspace result file (the .npz that reconstruct or fit writes)" in result.stderr
    assert "pickle" not in result.stderr
