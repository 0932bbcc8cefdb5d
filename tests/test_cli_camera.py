"""--intrinsics / --fov / --image-size on the command line: one camera, or exit code 2 with one line."""

from __future__ import annotations

import base64
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from chainspace import ChainspaceError, PinholeCamera
from chainspace.chain import KinematicChain
from chainspace.cli import _camera_option, app

runner = CliRunner()
DATA = Path(__file__).parent / "data" / "cameras"


def _run(*args):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


def test_camera_option_builds_the_camera():
    assert _camera_option(None, None, None) is None
    assert _camera_option(None, None, (640.0, 480.0)) is None  # an image size alone is no camera
    cam = _camera_option(None, 60.0, (640.0, 480.0))
    assert cam.image_size == (640, 480) and cam.fov_deg[0] == pytest.approx(60.0)
    assert _camera_option(DATA / "opencv_calibration.yml", None, None) == PinholeCamera.load(
        DATA / "opencv_calibration.yml")
    assert _camera_option(DATA / "opencv_calibration.yml", None, (640.0, 480.0)).image_size == (640, 480)


@pytest.mark.parametrize("intrinsics, fov, size, match", [
    (None, -10.0, (640.0, 480.0), "--fov must be"),
    (None, 0.0, (640.0, 480.0), "--fov must be"),
    (None, 180.0, (640.0, 480.0), "--fov must be"),
    (None, float("nan"), (640.0, 480.0), "--fov must be"),
    (None, float("inf"), (640.0, 480.0), "--fov must be"),
    (None, 60.0, None, "--fov needs the image size"),
    (None, 60.0, (640.5, 480.0), "--image-size must be"),
    (None, 60.0, (0.0, 480.0), "--image-size must be"),
    ("opencv_calibration.yml", 60.0, None, "not both"),
    ("missing.yml", None, None, r"missing\.yml: no such calibration file"),
    ("opencv_calibration.yml", None, (1280.0, 960.0), "640x480.*1280x960"),
])
def test_camera_option_rejects_bad_values(intrinsics, fov, size, match):
    path = None if intrinsics is None else DATA / intrinsics
    with pytest.raises(ChainspaceError, match=match):
        _camera_option(path, fov, size)


def _chain():
    names = ["pelvis", "spine", "head", "l_hip", "l_knee"]
    return KinematicChain(names, [("pelvis", "spine"), ("spine", "head"), ("pelvis", "l_hip"), ("l_hip", "l_knee")],
                          name="toy")


def _rec(F=8):
    """A reconstruction-like result seen by a weak camera 4 m in front of it."""
    rest = np.array([[0, 0, 1.0], [0, 0, 1.3], [0, 0, 1.7], [0, 0.1, 0.95], [0, 0.1, 0.5]])
    poses = rest + 0.02 * np.sin(np.arange(F)[:, None, None] / 3 + np.arange(3))
    R = Rotation.from_euler("x", -90, degrees=True).as_matrix()
    s = 800.0 / 4.0
    return SimpleNamespace(poses=poses, chain=_chain(), cameras=np.tile(s * R[:2], (F, 1, 1)),
                           translations=np.tile([320.0, 240.0], (F, 1)))


def _paths(html):
    import umsgpack

    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [umsgpack.unpackb(base64.b64decode(b)).get("path") for b in blobs]


@pytest.mark.parametrize("options", [["--intrinsics", DATA / "opencv_calibration.yml"],
                                     ["--fov", "55", "--image-size", "640", "480"],
                                     []])
def test_view_draws_the_camera_when_given(monkeypatch, tmp_path, options):
    pytest.importorskip("umsgpack")
    import chainspace.io.results as results

    monkeypatch.setattr(results, "load_results", lambda path: _rec())
    out = tmp_path / "v.html"
    result = _run("view", tmp_path / "rec.npz", "--html", out, *options)
    assert result.exit_code == 0, result.output
    assert ("/meshcat/chainspace/camera/frustum" in _paths(out.read_text())) == bool(options)


def test_view_bad_camera_options_exit_2_before_any_work(tmp_path):
    for options, message in [(["--fov", "-3", "--image-size", "640", "480"], "--fov must be"),
                             (["--fov", "60"], "--fov needs the image size"),
                             (["--intrinsics", tmp_path / "nope.yml"], "nope.yml: no such calibration file")]:
        result = _run("view", tmp_path / "missing.npz", "--html", tmp_path / "v.html", *options)
        assert result.exit_code == 2, result.output
        assert message in result.output and "Traceback" not in result.output
        assert not (tmp_path / "v.html").exists()


def test_view_needs_the_image_size_to_draw_a_calibration_without_one(tmp_path):
    (tmp_path / "k.json").write_text('{"K": [[800, 0, 320], [0, 800, 240], [0, 0, 1]]}')
    result = _run("view", tmp_path / "missing.npz", "--html", tmp_path / "v.html", "--intrinsics",
                  tmp_path / "k.json")
    assert result.exit_code == 2 and "--image-size" in result.output


@pytest.mark.parametrize("command", [["reconstruct", "tracks.csv", "--chain", "human17", "--out", "o"],
                                     ["fit", "tracks.csv", "--urdf", "milling_arm", "--out", "o"]])
def test_reconstruct_and_fit_validate_camera_options_first(tmp_path, command):
    args = [tmp_path / a if a in ("tracks.csv", "o") else a for a in command]
    result = _run(*args, "--fov", "200", "--image-size", "640", "480")
    assert result.exit_code == 2 and "--fov must be" in result.output
    result = _run(*args, "--intrinsics", tmp_path / "none.yml")
    assert result.exit_code == 2 and "none.yml: no such calibration file" in result.output


@pytest.mark.parametrize("command", ["reconstruct", "fit"])
def test_reconstruct_and_fit_pass_the_camera_on(monkeypatch, tmp_path, command):
    """The camera reaches the solver as intrinsics= when it takes them, and only then."""
    import chainspace.reconstruction.pipeline as pipeline
    import chainspace.robot.fit as robot_fit

    seen = {}

    class Stop(Exception):
        pass

    def solver(*args, intrinsics=None, **kwargs):
        seen["intrinsics"] = intrinsics
        raise Stop

    target = (pipeline, "reconstruct") if command == "reconstruct" else (robot_fit, "fit_joint_angles")
    monkeypatch.setattr(*target, solver)
    args = {"reconstruct": ["reconstruct", tmp_path / "t.csv", "--chain", "human17"],
            "fit": ["fit", tmp_path / "t.npz", "--urdf", "milling_arm"]}[command]
    tracks = tmp_path / "t.csv"
    if command == "reconstruct":
        from chainspace.io.datasets import human17
        from chainspace.io.tracks import save_tracks

        save_tracks(tracks, np.random.default_rng(0).uniform(0, 400, (5, 17, 2)), human17().joints)
    else:  # fit reads a reconstruction: stand one in
        import chainspace.cli as cli
        import chainspace.io.results as results

        monkeypatch.setattr(cli, "_is_result", lambda path: True)
        monkeypatch.setattr(results, "load_results", lambda path: SimpleNamespace(poses=np.zeros((2, 3, 3))))
    result = runner.invoke(app, [str(a) for a in args] + ["--out", str(tmp_path / "o"), "--fov", "50",
                                                          "--image-size", "640", "480"])
    assert result.exit_code == 3  # the stand-in solver's exception reads as an internal error
    assert seen["intrinsics"] == PinholeCamera.from_fov(640, 480, 50.0)


def _fit_keywords(monkeypatch, tmp_path, options: list[str]) -> dict:
    """The keywords ``chainspace fit`` hands fit_joint_angles for ``options``, a reconstruction stood in."""
    import chainspace.cli as cli
    import chainspace.io.results as results
    import chainspace.robot.fit as robot_fit

    seen = {}

    class Stop(Exception):
        pass

    def solver(*args, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(robot_fit, "fit_joint_angles", solver)
    monkeypatch.setattr(cli, "_is_result", lambda path: True)
    monkeypatch.setattr(results, "load_results", lambda path: SimpleNamespace(poses=np.zeros((2, 3, 3))))
    result = runner.invoke(app, ["fit", str(tmp_path / "t.npz"), "--urdf", "milling_arm",
                                 "--out", str(tmp_path / "o")] + options)
    assert result.exit_code == 3  # the stand-in solver's exception reads as an internal error
    return seen


@pytest.mark.parametrize("options, expected", [
    (["--image-size", "640", "480"], {"image_size": (640, 480)}),  # the focal length is then fitted
    (["--perspective"], {"perspective": True}),  # focal length and principal point fitted
    ([], {}),  # weak perspective
])
def test_fit_passes_an_image_size_alone_and_perspective_on(monkeypatch, tmp_path, options, expected):
    seen = _fit_keywords(monkeypatch, tmp_path, options)
    assert {k: seen[k] for k in ("image_size", "perspective", "intrinsics") if k in seen} == expected


@pytest.mark.parametrize("options, expected", [
    ([], dict(accel_std=3.0, jerk_std=10.0, speed_decay_s=None)),
    (["--accel-std", "40", "--jerk-std", "500", "--speed-decay", "0.5"],
     dict(accel_std=40.0, jerk_std=500.0, speed_decay_s=0.5)),
    (["--no-motion-prior"], dict(accel_std=None, jerk_std=None, speed_decay_s=None)),
])
def test_fit_passes_the_motion_prior_options(monkeypatch, tmp_path, options, expected):
    # the command line can set what fit_joint_angles takes (issue 21): the priors a fast robot needs
    seen = _fit_keywords(monkeypatch, tmp_path, options)
    assert {k: seen[k] for k in expected} == expected


@pytest.mark.parametrize("option", ["--accel-std", "--jerk-std", "--speed-decay"])
def test_fit_refuses_a_motion_prior_that_is_not_positive(tmp_path, option):
    result = runner.invoke(app, ["fit", str(tmp_path / "t.npz"), "--urdf", "milling_arm", option, "-1"])
    assert result.exit_code == 2 and f"{option} must be a finite number > 0, not -1" in result.output


def test_a_solver_without_intrinsics_is_a_clear_usage_error():
    import typer

    from chainspace.cli import _intrinsics_kwargs

    def old(W, chain):
        return None

    def new(W, chain, intrinsics=None):
        return None

    cam = PinholeCamera.from_fov(640, 480, 50.0)
    assert _intrinsics_kwargs(old, None, "reconstruct") == {}
    assert _intrinsics_kwargs(new, cam, "reconstruct") == {"intrinsics": cam}
    with pytest.raises(typer.Exit) as exc:
        _intrinsics_kwargs(old, cam, "reconstruct")
    assert exc.value.exit_code == 2
