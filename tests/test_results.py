"""atomic_write never leaves partial files and refuses to overwrite; results round-trip."""

from __future__ import annotations

import importlib
import json
from types import SimpleNamespace

import numpy as np
import pytest

from chainspace.chain import KinematicChain
from chainspace.errors import ChainspaceError, OutputExistsError
from chainspace.io.results import atomic_write, load_results, result_paths, save_results
from chainspace.robot.result import playback_fps


def _chain() -> KinematicChain:
    return KinematicChain(["root", "a", "b"], [("root", "a"), ("a", "b")], name="toy")


def _reconstruction(F: int = 4) -> SimpleNamespace:
    rng = np.random.default_rng(0)
    poses = rng.normal(size=(F, 3, 3))
    cams = np.tile(np.eye(3)[:2], (F, 1, 1))
    return SimpleNamespace(
        poses=poses, cameras=cams, translations=np.zeros((F, 2)), bone_lengths=np.array([1.0, 0.5]),
        tracks=poses[..., :2], confidence=None, chain=_chain(), method="default", converged=True, n_iter=7,
        message="converged", history={"kcs": {"reprojection": [3.0, 1.0, 0.5], "error_3d": [0.2, 0.1]}},
        timings={"kcs": 0.01}, reprojection_error=lambda: 0.5,
    )


def test_atomic_write_writes_and_refuses_to_overwrite(tmp_path):
    target = tmp_path / "sub" / "out.txt"
    with atomic_write(target) as f:
        f.write("first")
    assert target.read_text() == "first"
    with pytest.raises(OutputExistsError, match="out.txt.*overwrite"):
        with atomic_write(target) as f:
            f.write("second")
    assert target.read_text() == "first"
    with atomic_write(target, "w", overwrite=True) as f:
        f.write("third")
    assert target.read_text() == "third"
    assert sorted(p.name for p in target.parent.iterdir()) == ["out.txt"]


def test_atomic_write_leaves_target_untouched_on_error(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_write(target, "wb", overwrite=True) as f:
            f.write(b"partial")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"old"
    new = tmp_path / "new.bin"
    with pytest.raises(KeyboardInterrupt):
        with atomic_write(new, "wb") as f:
            f.write(b"partial")
            raise KeyboardInterrupt
    assert not new.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


def test_save_and_load_reconstruction(tmp_path):
    rec = _reconstruction()
    paths = save_results(rec, tmp_path)
    assert sorted(p.name for p in paths) == ["reconstruction.csv", "reconstruction.json", "reconstruction.npz"]
    back = load_results(tmp_path / "reconstruction.npz")
    np.testing.assert_allclose(back.poses, rec.poses)
    np.testing.assert_allclose(back.cameras, rec.cameras)
    assert back.chain.joints == rec.chain.joints and back.chain.bones == rec.chain.bones
    assert back.converged and back.n_iter == 7 and back.history["kcs"]["reprojection"] == [3.0, 1.0, 0.5]
    summary = json.loads((tmp_path / "reconstruction.json").read_text())
    assert summary["errors"]["reprojection_rms"] == 0.5
    assert summary["errors"]["error_3d_by_stage_m"] == {"kcs": 0.1}
    assert summary["joints"] == ["root", "a", "b"] and summary["units"]["poses"] == "m"
    lines = (tmp_path / "reconstruction.csv").read_text().splitlines()
    assert lines[0] == "frame,joint,x,y,z" and len(lines) == 1 + 4 * 3
    f, j, *xyz = lines[1 + 3 * 2 + 1].split(",")
    assert (f, j) == ("2", "a")
    np.testing.assert_allclose([float(v) for v in xyz], rec.poses[2, 1])
    # a second save refuses before writing anything, and --overwrite replaces all
    with pytest.raises(OutputExistsError):
        save_results(rec, tmp_path)
    rec.n_iter = 9
    save_results(rec, tmp_path / "reconstruction.npz", overwrite=True)
    assert load_results(tmp_path).n_iter == 9


def test_save_joint_fit(tmp_path):
    F = 5
    fit = SimpleNamespace(q=np.linspace(0, 1, F * 2).reshape(F, 2), joint_names=["j1", "j2"],
                          observable=np.array([True, False]), positions=np.zeros((F, 3, 3)),
                          residual_3d=np.full(F, 0.002), residual_px=None, converged=np.ones(F, bool), scale=1.0,
                          rotation=np.eye(3), translation=np.zeros(3), cameras=None, translations_2d=None,
                          chain=_chain().with_rest_pose(np.eye(3)), urdf_path="arm.urdf", message="ok", n_iter=3,
                          fps=25.0)
    fit.chain.metadata.update(q_rest=np.zeros(2), extra_frames={"tip": ("b", np.array([0.0, 0.0, 0.1]))})
    save_results(fit, tmp_path / "fit")
    header, *rows = (tmp_path / "fit" / "joint_angles.csv").read_text().splitlines()
    assert header == "frame,j1,j2" and len(rows) == F
    np.testing.assert_allclose([float(v) for v in rows[-1].split(",")[1:]], fit.q[-1])
    summary = json.loads((tmp_path / "fit" / "joint_angles.json").read_text())
    assert summary["residual_3d_mm"]["mean"] == pytest.approx(2.0)
    assert summary["converged_fraction"] == 1.0
    back = load_results(tmp_path / "fit" / "joint_angles.npz")
    assert back.joint_names == ["j1", "j2"] and back.urdf_path == "arm.urdf" and back.n_iter == 3
    # the frame rate the fit assumed plays it back (the plots' time axis, the viewer), unless one is given
    assert summary["fps"] == back.fps == 25.0 and playback_fps(back) == 25.0 and playback_fps(back, 60) == 60.0
    assert playback_fps(SimpleNamespace(fps=None)) == playback_fps(None) == 30.0
    np.testing.assert_allclose(back.q, fit.q)
    np.testing.assert_array_equal(back.observable, fit.observable)
    np.testing.assert_allclose(back.chain.rest_pose, np.eye(3))
    assert back.chain.metadata["extra_frames"] == {"tip": ["b", [0.0, 0.0, 0.1]]}


def test_result_paths_are_the_files_save_results_writes(tmp_path):
    """A folder gets reconstruction.*; a name with a result suffix is a stem (its suffix replaced)."""
    rec = _reconstruction()
    assert save_results(rec, tmp_path / "a") == result_paths(tmp_path / "a", "reconstruction")
    assert save_results(rec, tmp_path / "walk.csv") == result_paths(tmp_path / "walk.csv", "reconstruction")
    assert [p.name for p in result_paths("walk.csv", "reconstruction")] == ["walk.npz", "walk.csv", "walk.json"]
    assert [str(p) for p in result_paths("fit", "validation")] == ["fit/validation.json", "fit/validation.md"]
    with pytest.raises(ValueError, match="kind"):
        result_paths("x", "poses")


@pytest.mark.parametrize("name,content", [("tracks.csv", b"frame,joint,x,y\n0,a,1,2\n"), ("q.npy", None),
                                          ("other.npz", None)])
def test_a_file_that_is_no_result_is_said_to_be_none(tmp_path, name, content):
    """Not numpy's words about pickles: what the file is not, and what a result file is."""
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    elif name.endswith(".npy"):
        np.save(path, np.zeros(3))
    else:
        np.savez(path, x=np.zeros(3))
    with pytest.raises(ChainspaceError) as err:
        load_results(path)
    assert str(err.value) == f"{path}: not a chainspace result file (the .npz that reconstruct or fit writes)"


def test_save_results_rejects_unknown_objects(tmp_path):
    with pytest.raises(ChainspaceError, match="cannot save"):
        save_results(object(), tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_real_reconstruction_round_trip(tmp_path):
    rec_mod = importlib.import_module("chainspace.reconstruction.pipeline")
    datasets = importlib.import_module("chainspace.io.datasets")
    synthetic = importlib.import_module("chainspace.synthetic.views")
    chain, poses = datasets.human17(), datasets.cmu_walk(35, 1)[:40]
    tracks = synthetic.observe(poses, synthetic.orbit_cameras(len(poses), seed=1, scale=300.0), seed=2)
    rec = rec_mod.reconstruct(tracks, chain, truth=poses, seed=0)
    save_results(rec, tmp_path)
    back = load_results(tmp_path / "reconstruction.npz")
    assert isinstance(back, rec_mod.Reconstruction)
    np.testing.assert_allclose(back.poses, rec.poses)
    assert back.chain.joints == chain.joints and back.method == rec.method and back.converged == rec.converged
    assert back.reprojection_error() == pytest.approx(rec.reprojection_error())
    assert back.history["kcs"]["reprojection"] == pytest.approx(rec.history["kcs"]["reprojection"])
