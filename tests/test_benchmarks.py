"""Every benchmark runner in benchmarks/ runs at its smallest setting and prints its table; the tables
count every run (issue 21: a benchmark that cannot hide a failure)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from chainspace.bench.full_range import compare_full_range, format_full_range, summarise
from chainspace.bench.hidden_ends import format_hidden_ends
from chainspace.bench.robustness import check_targets, find_cliffs

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
# each script's smallest setting (a few frames, one robot or sequence) and a string its output must hold;
# a script not listed here is run with --quick (other suites: give them a small setting here)
SMALLEST = {
    "bench_full_range.py": (["--robots", "double_pendulum", "--frames", "6", "--settings", "full, below"],
                            "| double_pendulum | 1 | "),
    # the 2-joint double pendulum: a 6-axis arm's fit takes half a minute even on 8 frames
    "bench_robots.py": (["--robots", "double_pendulum", "--frames", "8", "--seeds", "1", "--static-1px"],
                        "| double_pendulum |"),
    "bench_pinhole_robots.py": (["--robots", "double_pendulum", "--conditions", "K", "--frames", "8"],
                                "| double_pendulum | K |"),
    "bench_hidden_ends.py": (["--robot", "double_pendulum", "--trials", "1", "--frames", "9", "--decays", "none"],
                             "| none | 2 |"),
    "bench_robustness.py": (["--quick", "--datasets", "walk35", "--cameras", "1", "--sweeps", "noise"],
                            "### walk35"),
    "bench_static_camera.py": (["--set", "tune", "--quick", "--frames", "40"], "| tune | straight | 0 | 1 |"),
    # render, find the markers and track their centres on 4 frames; the two joint fits would take 30 s more
    "bench_video.py": (["--quick", "--frames", "4", "--no-fit"], "| milling_arm | 640x480 | 4 |"),
    # --quick times 1,000 and 10,000 frames, each for a second per method and thread count (23 s)
    "bench_speed.py": (["--sizes", "500"], "| 500 |"),
    "bench_uncertainty.py": (["--robot", "double_pendulum", "--trials", "1", "--frames", "6"],
                             "a static pinhole camera"),
    "bench_no_camera.py": (["--robots", "double_pendulum", "--seeds", "1", "--frames", "8"],
                           "| double_pendulum | 0 |"),
}
# bench_batch.py starts two Dask clusters and a fresh process (tens of seconds even --quick): its pieces
# are run here instead (test_batch_benchmark_recordings)
SLOW = {"bench_batch.py"}
# bench_fit_speed.py --quick fits the milling arm (half a minute): the robot-fit runners above cover its code
# path on the double pendulum, so it is given the smallest robot here too
SMALLEST["bench_fit_speed.py"] = (["--robots", "double_pendulum", "--frames", "8"], "| double_pendulum |")


def _main(name: str):
    spec = importlib.util.spec_from_file_location(name[:-3], BENCH / name)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.main


@pytest.mark.parametrize("name", sorted(p.name for p in BENCH.glob("bench_*.py")
                                        if p.name not in SLOW | {"bench_reconstruction.py"}))
def test_every_benchmark_runs_its_smallest_setting(name, capsys, monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    argv, expect = SMALLEST.get(name, (["--quick"], "|"))
    rc = _main(name)(argv)
    out = capsys.readouterr().out
    assert rc in (0, 1), f"{name} exited {rc}"  # 1: a target missed, which the table says
    assert expect in out, out[-2000:]


@pytest.mark.parametrize("robot", [None, "milling_arm"])
def test_batch_benchmark_recordings(tmp_path, robot):
    spec = importlib.util.spec_from_file_location("bench_batch", BENCH / "bench_batch.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    recs = mod.read_manifest(mod.make_recordings(tmp_path, 1, 12, robot))
    res = mod.process_recording(recs[0], tmp_path / "out")
    assert res["cpu_seconds"] > 0 and len(recs) == 1
    assert recs[0].is_robot == (robot is not None)
    # a robot's recording is reconstructed and fitted: its joint angles are written too
    assert (tmp_path / "out" / recs[0].name / "joint_angles.csv").is_file() == (robot is not None)


def test_reconstruction_benchmark_without_its_data_says_skipped(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("CHAINSPACE_DATA", str(tmp_path))  # an empty data folder: no CMU, no DeepMimic
    from chainspace.bench import reconstruction

    monkeypatch.setattr(reconstruction, "sequence_groups", lambda *a, **k: {})
    rc = _main("bench_reconstruction.py")(["--quick"])
    assert rc == 77 and "skipped: no benchmark data" in capsys.readouterr().err


def test_static_camera_benchmark_without_its_data_says_skipped(capsys, monkeypatch, tmp_path):
    """The held-out walks are not bundled: without the shared data the set is a row saying so, and the
    script exits 77 (`make bench`: skipped), not with a traceback."""
    monkeypatch.setenv("CHAINSPACE_DATA", str(tmp_path))  # an empty data folder
    rc = _main("bench_static_camera.py")(["--quick", "--set", "held out"])
    out, err = capsys.readouterr()
    assert rc == 77 and "data missing" in out and "skipped: no data" in err


def _run(robot, outcome="fit", errors=(), statuses=None, setting="full, above"):
    statuses = statuses or ["observable"] * len(errors)
    joints = [dict(name=f"j{k}", status=s, error=e, unit="deg",
                   verdict="ok" if e <= 2 else ("flagged" if s not in ("observable", "relative to frame 0") else "silent"),
                   reason=s) for k, (e, s) in enumerate(zip(errors, statuses))]
    return dict(robot=robot, setting=setting, seed=0, outcome=outcome, joints=joints if outcome == "fit" else [],
                error_3d_mm=1.0 if outcome == "fit" else np.nan, seconds=1.0, note="boom" if outcome != "fit" else "")


def test_full_range_table_counts_silent_flags_and_failures():
    runs = [_run("good", errors=(0.5, 1.0)),
            _run("flagged", errors=(0.5, 177.0), statuses=["observable", "ambiguous"]),
            _run("silent", errors=(0.5, 177.0)), _run("silent", outcome="crashed"),
            _run("refused", outcome="refused")]
    rows = {r["robot"]: r for r in summarise(runs)}
    assert rows["good"]["verdict"] == "met" and rows["flagged"]["verdict"] == "met"
    assert rows["flagged"]["flagged"] == 1 and rows["flagged"]["judged"] == [0.5]  # the flag's error apart
    assert rows["silent"]["verdict"] == "missed" and rows["silent"]["crashed"] == 1 and rows["silent"]["silent"] == 1
    assert rows["refused"]["verdict"] == "refused"
    text = format_full_range(runs)
    assert "Target met on 2 of 4 robots" in text and "j1 (full, above, 177 deg)" in text and "boom" in text


def test_full_range_comparison_counts_both_sets_and_names_each_changed_run():
    old = [_run("a", errors=(0.5, 1.0)), _run("b", errors=(0.5, 177.0), statuses=["observable", "ambiguous"]),
           _run("c", errors=(0.5, 0.7))]
    new = [_run("a", errors=(0.5, 177.0)), _run("b", errors=(0.6, 177.0), statuses=["observable", "ambiguous"]),
           _run("c", errors=(0.5, 1.9)), _run("d", outcome="crashed")]
    text = compare_full_range(old, new)
    assert "| old | 3 | 5 | 1 | 0 | 0 | 0 | 0 |" in text and "| new | 4 | 4 | 1 | 1 | 1 | 0 | 1 |" in text, text
    assert "Runs that changed (2 of 3):" in text  # a (now silent) and c (its worst ok joint 1.2 deg further)
    assert "a full, above seed 0: old fit, silent -, flagged -, worst ok 1.00 deg; new fit, silent j1" in text
    assert "- b full" not in text and "d full, above seed 0: only in the new set" in text


def test_full_range_saved_runs_from_the_command_line(tmp_path, capsys):
    old, new, bad = tmp_path / "old.json", tmp_path / "new.json", tmp_path / "bad.json"
    old.write_text(json.dumps([_run("a", errors=(0.5, 1.0))]))
    new.write_text(json.dumps([_run("a", errors=(0.5, 177.0))]))
    bad.write_text(json.dumps({"robot": "a"}))
    assert _main("bench_full_range.py")(["--compare", str(old), str(new)]) == 0
    assert "Runs that changed (1 of 1):" in capsys.readouterr().out
    # saved runs record neither camera nor frame count: the table says so rather than guess
    _main("bench_full_range.py")(["--from-json", str(old)])
    assert "camera not recorded (give --camera); 1 px noise. " in capsys.readouterr().out
    _main("bench_full_range.py")(["--from-json", str(old), "--camera", "static", "--frames", "30"])
    assert "camera static; 1 px noise; 30 frames per run" in capsys.readouterr().out
    for args, says in ((["--compare", str(tmp_path / "gone.json"), str(new)], "--compare: cannot read"),
                       (["--compare", str(bad), str(new)], "not a list"),
                       (["--from-json", str(old), str(bad)], f"--from-json: {bad} is not a list")):
        with pytest.raises(SystemExit):
            _main("bench_full_range.py")(args)
        assert says in capsys.readouterr().err


def test_hidden_ends_table_keeps_a_flipped_run_in_its_mean_and_max():
    rows = [dict(trial=k, end="last", decay=None, worst_deg=w, error_mm=10.0, silent=["a4"] if w > 90 else [])
            for k, w in enumerate((4.0, 5.0, 177.0))]
    line = format_hidden_ends(rows).splitlines()[-1]
    assert line.startswith("| none | 3 | 1 | 1 | 62.00 | 177.00 |"), line


def test_robustness_targets_judge_joints_and_failed_runs():
    base = dict(dataset="milling arm", noise_px=2.0, hidden=0.0, ratio=1.0, silent_flips=0, runs=1, failed=0)
    rows = [dict(base, sweep="random", missing=m, hidden=m, error_mm=8.0, joint_rms_deg=d)
            for m, d in ((0.0, 1.0), (0.2, 1.1), (0.4, 178.0))]
    rows[2]["silent_flips"] = 1
    res = {name: ok for name, ok, _ in check_targets(rows)}
    assert res["milling arm: no cliff in the random sweep"]  # every point in place
    assert not res["milling arm: no cliff in the random sweep (worst joint RMS)"]  # the flipped wrist
    assert not res["milling arm: no silent flip (a joint > 90 deg off, reported observable)"]
    assert find_cliffs([0, 1, 2], [5.0, 6.0, np.inf])["cliff"][-1]  # a failed run is a cliff


def test_uncertainty_benchmark_keeps_weak_and_pinhole_trials_apart(tmp_path, capsys):
    main, saved = _main("bench_uncertainty.py"), tmp_path / "u.json"
    argv = ["--robot", "double_pendulum", "--trials", "1", "--frames", "6", "--json", str(saved)]
    assert main(argv + ["--camera", "static"]) == 0
    assert "weak-perspective camera" in capsys.readouterr().out
    with pytest.raises(SystemExit):  # the file holds a weak-perspective trial: no pinhole ones added to it
        main(argv)
    assert "another robot, frame count, noise or camera" in capsys.readouterr().err
    assert main(["--from-json", str(saved)]) == 0 and "weak-perspective camera" in capsys.readouterr().out
    other = tmp_path / "v.json"  # the same trial relabelled pinhole: not tabled under the first file's title
    other.write_text(saved.read_text().replace('"static"]', '"pinhole"]'))
    with pytest.raises(SystemExit):
        main(["--from-json", str(saved), str(other)])


def test_uncertainty_model_check_ranks_a_trial_among_draws_from_its_covariance():
    check = _main("bench_uncertainty.py").__globals__["_model_check"]
    rng = np.random.default_rng(0)
    n = 120
    G = rng.normal(size=(n, n))
    cov = 0.2 * G @ G.T / n + 0.8 * np.full((n, n), 1.0) + 0.1 * np.eye(n)  # one shared direction, as a camera
    std = np.sqrt(np.diag(cov))
    honest = np.linalg.cholesky(cov) @ rng.normal(size=n)
    res = check(honest, std, cov, seed=1)
    assert 0.5 < res["chi2_dof"] < 1.5 and 0.0 <= res["model_rank"] <= 1.0
    lo, mid, hi = res["model_shares"]
    assert lo < 0.5 and hi > 0.8  # a shared direction spreads a trial's share widely
    assert check(np.zeros(n), std, cov, seed=1)["model_rank"] > 0.9  # every error inside: above the draws
    flipped = check(10 * std * (-1) ** np.arange(n), std, cov, seed=1)  # far off, across the shared direction
    assert flipped["model_rank"] < 0.05 and flipped["chi2_dof"] > 10  # all outside: below (nearly) every draw


def test_pinhole_robots_json_resumes_and_its_table_counts_judged_and_flagged_joints(tmp_path, capsys, monkeypatch):
    """--json saves each run as it comes, a second call runs nothing already saved, --from-json prints the
    same table; the table counts the judged joints and lists a flagged one with its error apart."""
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    main = _main("bench_pinhole_robots.py")
    path = tmp_path / "runs.json"
    argv = ["--robots", "double_pendulum", "--conditions", "K", "--frames", "8", "--json", str(path)]
    assert main(argv) == 0
    first = capsys.readouterr()
    runs = json.loads(path.read_text())
    assert [(r["robot"], r["cond"], r["seed"], r["frames"]) for r in runs] == [("double_pendulum", "K", 0, 8)]
    assert main(argv) == 0  # resumed: nothing left to run
    again = capsys.readouterr()
    assert "seed 0" in first.err and "seed 0" not in again.err
    assert json.loads(path.read_text()) == runs and again.out == first.out
    assert main(["--from-json", str(path)]) == 0
    assert capsys.readouterr().out == first.out

    # a flagged joint: listed apart with its error, not judged, not the worst; a failed run counts as infinite
    # (its worst judged joint given: the pendulum at 8 frames may itself flag joint1 with a tie, leaving none)
    flagged = dict(runs[0], worst_deg=0.5, joints=[dict(j) for j in runs[0]["joints"]])
    flagged["joints"][0].update(status="ambiguous", judged=False, reason="tie", rms=37.5)
    failed = dict(robot="double_pendulum", cond="K", seed=1, frames=8, error="ValueError: x")
    out = _main("bench_pinhole_robots.py").__globals__["table"]([flagged, failed])
    row = next(l for l in out.splitlines() if l.startswith("| double_pendulum | K | 8 |"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[3:5] == ["2", "1"] and cells[5].startswith("inf / inf")
    assert cells[6].startswith("0 of 2") and cells[7] == f"{flagged['joints'][0]['name']} 37.50 (tie)"
    assert "Failed runs:" in out and "seed 1: ValueError: x" in out


def test_full_range_judges_a_flagged_relative_joint_by_its_change_and_names_each_joints_reason():
    # a joint seen only relative to frame 0 is compared without its offset also when flagged (the
    # Panda's first joint was counted 51 degrees off for a 1 degree error), and a flagged joint's reason
    # is its own (the fit's joint_reasons), not the first sentence of the message that names it
    import dataclasses
    from types import SimpleNamespace

    from chainspace.bench.full_range import judge_joints
    from chainspace.io.urdf import from_urdf
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.synthetic.robot import synthesize

    chain = from_urdf(Path(__file__).resolve().parents[1] / "robots" / "milling_arm.urdf")
    t = synthesize(chain, n_frames=8, noise_px=0.0, seed=11, camera="static")
    fit = fit_joint_angles(t.positions, chain=chain, transform="none")
    reasons = ["tie: 1 other motion(s) fit the tracks as well", "", "", "uncertain: standard deviation 2.4 deg", "", ""]
    flagged = dataclasses.replace(fit, relative=np.arange(6) == 0, observable=np.arange(6) != 0,
                                  ambiguous=np.array([r != "" for r in reasons]), joint_reasons=reasons,
                                  message="ambiguous: joint_a1, joint_a4 (a message naming both)")
    truth = t.q.copy()
    truth[:, 0] += 0.7  # the relative joint's offset
    truth[:, 3] += np.radians(5.0)  # 5 degrees off on a flagged joint
    rows = {j["name"]: j for j in judge_joints(flagged, SimpleNamespace(q=truth))}
    assert rows["joint_a1"]["status"] == "ambiguous" and rows["joint_a1"]["error"] < 1e-3
    assert rows["joint_a1"]["verdict"] == "ok"
    assert rows["joint_a4"]["verdict"] == "flagged" and rows["joint_a4"]["error"] == pytest.approx(5.0, abs=1e-3)
    assert rows["joint_a4"]["reason"] == f"ambiguous ({reasons[3]})"
    assert all(rows[n]["verdict"] == "ok" for n in ("joint_a2", "joint_a3", "joint_a5", "joint_a6"))
