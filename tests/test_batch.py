"""Batch processing on Dask (chainspace.batch, ``chainspace batch``): a manifest of small human
recordings and one broken row through a local cluster of two worker processes, resumed; bad
manifests; the intrinsics/fps columns against the stages' signatures."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("dask.distributed")

import chainspace as cs  # noqa: E402
from chainspace import batch as B  # noqa: E402
from chainspace.synthetic.views import observe, orbit_cameras, swing_motion  # noqa: E402

HEADER = "name,tracks,chain,fps\n"


def _human_tracks(folder: Path, name: str, seed: int, frames: int = 60) -> Path:
    human = cs.shipped("human17")
    X = swing_motion(human, frames, seed=seed)
    W = observe(X, orbit_cameras(frames, scale=400.0, seed=seed + 100), translations=[450.0, 450.0],
                noise_px=0.5, seed=seed)
    path = folder / "tracks" / f"{name}.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    cs.save_tracks(path, W, human.joints)
    return path


@pytest.fixture
def manifest(tmp_path: Path) -> Path:
    """Three human recordings (one with its chain as a description file) and a row whose tracks are missing."""
    for i, name in enumerate(("walk_a", "walk_b", "walk_c")):
        _human_tracks(tmp_path, name, seed=i)
    human_toml = cs.shipped_path("human17")
    path = tmp_path / "manifest.csv"
    path.write_text(HEADER
                    + "walk_a,tracks/walk_a.csv,human17,\n"
                    + f"walk_b,tracks/walk_b.csv,{human_toml},\n"
                    + "# a comment line\n"
                    + "walk_c,tracks/walk_c.csv,human17,\n"
                    + "lost,tracks/lost.csv,human17,\n", encoding="utf-8")
    return path


def test_read_manifest_resolves_paths_and_reports_row_problems(manifest):
    with pytest.raises(B.ManifestError, match=r"manifest\.csv:6: column 'tracks': no such file: tracks/lost\.csv"):
        cs.read_manifest(manifest)
    recs = cs.read_manifest(manifest, strict=False)
    assert [r.name for r in recs] == ["walk_a", "walk_b", "walk_c", "lost"]
    assert [r.line for r in recs] == [2, 3, 5, 6]
    assert recs[0].tracks == manifest.parent / "tracks" / "walk_a.csv" and recs[0].tracks.is_absolute()
    assert recs[0].chain == "human17" and Path(recs[1].chain).is_file()
    assert recs[0].fps is None and not recs[0].is_robot
    assert [r.problem is None for r in recs] == [True, True, True, False]


@pytest.mark.parametrize("text, message", [
    ("name,tracks\nx,t.csv\n", r":1: the header lacks the column 'chain'"),
    ("name,tracks,chain,fsp\nx,t.csv,human17,30\n", r":1: unknown column 'fsp'"),
    ("name,tracks,chain\n", r"header but no recordings"),
    ("", r"the manifest is empty"),
    ("name,tracks,chain\nx,t.csv,human17\nx,t.csv,human17\n", r":3: column 'name': 'x' is already the name on line 2"),
    ("name,tracks,chain\n../up,t.csv,human17\n", r":2: column 'name': the name '../up' cannot be a folder name"),
    ("name,tracks,chain\nx,t.csv,human17,extra\n", r":2: 4 values for 3 columns"),
])
def test_bad_manifests_are_refused_as_a_whole(tmp_path, text, message):
    (tmp_path / "t.csv").write_text("frame\n", encoding="utf-8")
    path = tmp_path / "manifest.csv"
    path.write_text(text, encoding="utf-8")
    for strict in (True, False):
        with pytest.raises(B.ManifestError, match=message):
            cs.read_manifest(path, strict=strict)
    with pytest.raises(B.ManifestError, match=message):
        cs.run_batch(path, tmp_path / "out", progress=False)  # before any cluster is started
    assert not (tmp_path / "out" / "summary.csv").exists()


@pytest.mark.parametrize("row, message", [
    ("x,t.csv,humn17,", r":2: column 'chain': unknown chain: no shipped description 'humn17'.*Did you mean"),
    ("x,t.csv,skeletons/mine.toml,", r":2: column 'chain': no such description file: skeletons/mine.toml"),
    ("x,t.csv,human17,fast", r":2: column 'fps': 'fast' is not a number"),
    ("x,t.csv,human17,-30", r":2: column 'fps': '-30' is not a positive number"),
    ("x,,human17,30", r":2: column 'tracks': is empty"),
])
def test_bad_rows_name_the_line_and_column(tmp_path, row, message):
    (tmp_path / "t.csv").write_text("frame\n", encoding="utf-8")
    path = tmp_path / "manifest.csv"
    path.write_text(HEADER + row + "\n", encoding="utf-8")
    with pytest.raises(B.ManifestError, match=message):
        cs.read_manifest(path)
    (rec,) = cs.read_manifest(path, strict=False)
    assert rec.problem is not None and "manifest.csv:2" in rec.problem


def test_batch_on_a_two_worker_cluster_then_resumed(manifest, tmp_path):
    out = tmp_path / "out"
    result = cs.run_batch(manifest, out, n_workers=2, progress=False)

    assert result.failed == ["lost"] and result.not_good == [] and result.skipped == []
    assert not result.ok
    rows = {r["name"]: r for r in result.rows}
    assert [r["name"] for r in result.rows] == ["walk_a", "walk_b", "walk_c", "lost"]
    for name in ("walk_a", "walk_b", "walk_c"):
        r = rows[name]
        assert r["status"] == "ok" and r["converged"] is True and r["frames"] == 60 and r["kind"] == "chain"
        assert 0 < r["reprojection_px"] < 5 and r["seconds"] > 0
        for f in ("reconstruction.npz", "reconstruction.csv", "reconstruction.json", B.DONE_MARKER):
            assert (out / name / f).is_file(), f
        assert json.loads((out / name / B.DONE_MARKER).read_text())["frames"] == 60
    assert rows["lost"]["status"] == "failed" and "manifest.csv:6: column 'tracks'" in rows["lost"]["error"]
    assert not (out / "lost").exists()
    assert not list(out.glob(".*partial*"))  # no temporary folder left behind

    with open(result.summary_csv, newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert [t["name"] for t in table] == ["walk_a", "walk_b", "walk_c", "lost"]
    assert [t["status"] for t in table] == ["ok", "ok", "ok", "failed"]
    assert float(table[0]["reprojection_px"]) == pytest.approx(rows["walk_a"]["reprojection_px"], rel=1e-3)
    page = result.summary_html.read_text(encoding="utf-8")
    assert "<table>" in page and "walk_c" in page and "no such file" in page

    # the second run skips what is finished and retries the failed row, now fixed
    before = (out / "walk_a" / "reconstruction.npz").stat().st_mtime_ns
    _human_tracks(tmp_path, "lost", seed=7)
    again = cs.run_batch(manifest, out, n_workers=2, progress=False)
    assert again.skipped == ["walk_a", "walk_b", "walk_c"] and again.failed == [] and again.ok
    assert (out / "walk_a" / "reconstruction.npz").stat().st_mtime_ns == before
    assert {r["name"]: r["status"] for r in again.rows} == dict.fromkeys(["walk_a", "walk_b", "walk_c", "lost"], "ok")
    assert again.rows[0]["reprojection_px"] == pytest.approx(rows["walk_a"]["reprojection_px"])
    assert (out / "lost" / B.DONE_MARKER).is_file()


def test_process_recording_is_atomic_and_refuses_foreign_folders(manifest, tmp_path, monkeypatch):
    rec = cs.read_manifest(manifest, strict=False)[0]
    out = tmp_path / "out"

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("chainspace.io.results.write_json", broken)
    with pytest.raises(OSError, match="No space left"):
        B.process_recording(rec, out)
    assert list(out.iterdir()) == []  # neither the folder nor a temporary one
    monkeypatch.undo()

    (out / rec.name).mkdir()
    with pytest.raises(cs.OutputExistsError, match="not a finished batch output"):
        B.process_recording(rec, out)
    (out / rec.name).rmdir()
    figures = B.process_recording(rec, out)
    assert figures["status"] == "ok" and (out / rec.name / B.DONE_MARKER).is_file()


def test_fps_and_intrinsics_go_only_to_stages_that_take_them(manifest, tmp_path):

    rec = cs.read_manifest(manifest, strict=False)[0]
    rec.intrinsics = tmp_path / "K.npy"

    def taking(tracks, chain, *, intrinsics=None, fps=None):
        pass

    def not_taking(tracks, chain, *, confidence=None, **kwargs):  # a catch-all does not count
        pass

    K = str(rec.intrinsics)
    assert B._options(rec, {"reconstruct": taking}) == {"reconstruct": {"intrinsics": K}}
    assert B._options(rec, {"reconstruct": not_taking, "fit": taking}) == {"reconstruct": {}, "fit": {"intrinsics": K}}
    with pytest.raises(cs.ChainspaceError, match=r"manifest\.csv:2: column 'intrinsics': intrinsics are not "
                                                 r"supported by this version .*reconstruct does not take"):
        B._options(rec, {"reconstruct": not_taking})
    rec.intrinsics, rec.fps = None, 30.0
    assert B._options(rec, {"reconstruct": not_taking, "fit": taking}) == {"reconstruct": {}, "fit": {"fps": 30.0}}
    # a frame rate no stage models (a reconstruction alone) is metadata, not an error
    assert B._options(rec, {"reconstruct": not_taking}) == {"reconstruct": {}}

    # and through process_recording: a calibration file in the intrinsics column reaches reconstruct
    camera = cs.PinholeCamera.from_fov(1280, 720, 60.0)
    rec.fps, rec.intrinsics = None, camera.save(tmp_path / "camera.json")
    figures = B.process_recording(rec, tmp_path / "out")
    assert figures["status"] == "ok", figures
    saved = cs.load_results(tmp_path / "out" / rec.name / "reconstruction.npz")
    assert saved.intrinsics == camera


def test_cli_exit_codes(manifest, tmp_path):
    from typer.testing import CliRunner

    from chainspace.cli import app

    runner = CliRunner()
    res = runner.invoke(app, ["batch", str(manifest), "--out", str(tmp_path / "out"), "--workers", "2",
                              "--no-progress"])
    assert res.exit_code == 1, res.output
    assert "| walk_a | ok | 60 |" in res.stdout and "| lost | failed |" in res.stdout
    assert "error: 1 recording failed, 0 did not converge" in res.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("name,tracks\nx,y\n", encoding="utf-8")
    res = runner.invoke(app, ["batch", str(bad), "--out", str(tmp_path / "out2")])
    assert res.exit_code == 2 and "lacks the column 'chain'" in res.output


@pytest.mark.slow
def test_a_tiny_robot_recording_is_fitted_and_validated(tmp_path):
    """One 20-frame milling-arm recording with its true joint angles: reconstructed, fitted, validated."""
    trial = cs.synthesize(str(cs.shipped_path("milling_arm")), n_frames=20, seed=4, camera="static")
    cs.save_tracks(tmp_path / "arm.npz", trial.tracks, trial.chain.joints, trial.confidence)
    np.save(tmp_path / "arm_q.npy", trial.q)
    (tmp_path / "m.csv").write_text("name,tracks,chain,truth\narm,arm.npz,milling_arm,arm_q.npy\n")
    (rec,) = cs.read_manifest(tmp_path / "m.csv")
    assert rec.is_robot
    fig = B.process_recording(rec, tmp_path / "out")
    assert fig["kind"] == "robot" and fig["frames"] == 20
    fitted = cs.load_results(tmp_path / "out" / "arm" / "joint_angles.npz")
    assert fig["worst_joint"] in list(fitted.joint_names) and fig["worst_joint_rms"] >= 0
    assert 0 <= fig["fit_converged_fraction"] <= 1 and fig["fit_reprojection_px"] is not None
    assert fig["validation_passed"] in (True, False)
    for stem in ("reconstruction", "joint_angles", "validation"):
        assert (tmp_path / "out" / "arm" / f"{stem}.json").is_file()
