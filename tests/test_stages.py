"""The robot fit's stages, logged (chainspace.progress.STAGES) and printed by the command line with the
elapsed time: the fit runs for minutes on long clips and used to say nothing meanwhile (issue 21)."""

from __future__ import annotations

import logging

import numpy as np
from typer.testing import CliRunner

import chainspace.progress as progress
from chainspace.bench.robots import robot_chain
from chainspace.cli import app
from chainspace.io.tracks import save_tracks
from chainspace.reconstruction.pipeline import reconstruct
from chainspace.robot.fit import fit_joint_angles
from chainspace.synthetic.robot import synthesize


def test_steps_log_the_first_then_at_most_one_every_few_seconds(monkeypatch, caplog):
    clock = iter([0.0, 0.5, 1.0, 3.2, 3.5, 9.0])  # stage_steps' start, then one reading per step
    monkeypatch.setattr(progress.time, "perf_counter", lambda: next(clock))
    with caplog.at_level(logging.INFO, logger="chainspace.stages"):
        step = progress.stage_steps("fitting start", 5, every_s=2.0)
        for done in range(5):
            step(done)
    assert [r.getMessage() for r in caplog.records] == [
        "fitting start 1/5",  # at 0.5 s
        "fitting start 3/5, about 5 s left in this stage",  # 3.2 s: 1.6 s a step so far, 3 steps left
        "fitting start 5/5, about 2 s left in this stage",  # 9.0 s: 2.25 s a step, 1 left
    ]


def test_print_stages_prints_lines_with_the_elapsed_time_and_restores_the_logger(capsys):
    before = (progress.STAGES.level, progress.STAGES.propagate, list(progress.STAGES.handlers))
    with progress.print_stages():
        progress.stage("robot fit: %d candidates", 2)
    progress.stage("not printed after the block")
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].endswith("s] robot fit: 2 candidates") and err[0].startswith("[")
    assert (progress.STAGES.level, progress.STAGES.propagate, list(progress.STAGES.handlers)) == before


def test_the_perspective_fit_logs_its_stages_in_order(caplog):
    chain = robot_chain("milling arm")
    trial = synthesize(chain, n_frames=20, noise_px=1.0, seed=4)
    rec = reconstruct(trial.tracks, chain, seed=4)
    with caplog.at_level(logging.INFO, logger="chainspace.stages"):
        fit_joint_angles(rec, intrinsics=trial.intrinsics)
    messages = [r.getMessage() for r in caplog.records if r.name == "chainspace.stages"]
    expected = ["robot fit through a pinhole camera: first its weak-perspective start, on all 20 frames",
                "weak start, 20 frames: the 3D points",
                "robot fit: refining on the tracks, candidate 1/", "robot fit, perspective: the camera from start 1/",
                "robot fit, perspective: refining in full, start 1/", "robot fit, perspective: other minima",
                "robot fit, perspective: the joint angles' standard deviations"]
    found = [next((i for i, m in enumerate(messages) if m.startswith(e)), None) for e in expected]
    assert None not in found and found == sorted(found), messages
    other = next(m for m in messages if m.startswith("robot fit, perspective: other minima"))
    assert other.endswith("search 1/6"), other  # a counted stage (its six searches)


def test_a_long_perspective_fit_says_its_weak_start_sees_some_frames(caplog, monkeypatch):
    """The weak start of a long clip sees every stride-th frame: said so, not "robot fit, N frames"."""
    from chainspace.robot import fit as fit_module

    chain = robot_chain("milling arm")
    trial = synthesize(chain, n_frames=20, noise_px=1.0, seed=4)
    rec = reconstruct(trial.tracks, chain, seed=4)
    monkeypatch.setattr(fit_module, "START_FRAMES", 10)  # 20 frames as a long clip: every 2nd seen
    with caplog.at_level(logging.INFO, logger="chainspace.stages"):
        fit_joint_angles(rec, intrinsics=trial.intrinsics, search_ties=False)
    messages = [r.getMessage() for r in caplog.records if r.name == "chainspace.stages"]
    assert "robot fit through a pinhole camera: first its weak-perspective start, on 10 of 20 frames" in messages
    assert any(m.startswith("weak start, 10 frames: the 3D points") for m in messages), messages
    assert not any(m.startswith("robot fit, 10 frames") for m in messages), messages


def test_the_weak_fit_counts_its_smoothed_choice(caplog):
    """The weak fit's choice with the motion prior, a stage of many seconds, logs its count too."""
    chain = robot_chain("milling arm")
    trial = synthesize(chain, n_frames=20, noise_px=1.0, seed=4, camera="static")
    rec = reconstruct(trial.tracks, chain, seed=4)
    with caplog.at_level(logging.INFO, logger="chainspace.stages"):
        fit_joint_angles(rec)
    messages = [r.getMessage() for r in caplog.records if r.name == "chainspace.stages"]
    assert any(m.startswith("robot fit: the motion prior, scoring fit 1/") for m in messages), messages


def test_the_fit_command_prints_the_stages_when_piped(tmp_path):
    chain = robot_chain("milling arm")
    trial = synthesize(chain, n_frames=20, noise_px=1.0, seed=5, camera="static")
    save_tracks(tmp_path / "tracks.csv", trial.tracks, chain.joints)
    result = CliRunner().invoke(app, ["fit", str(tmp_path / "tracks.csv"), "--urdf", "milling_arm", "-o",
                                      str(tmp_path / "fit")])
    assert result.exit_code in (0, 1), result.output
    lines = [ln for ln in result.stderr.splitlines() if "] robot fit" in ln]
    assert lines[0].startswith("[") and "robot fit, 20 frames: the 3D points" in lines[0]
    assert any("the joint angles' standard deviations" in ln for ln in lines)
    seconds = [float(ln[1:ln.index(" s]")]) for ln in lines]
    assert seconds == sorted(seconds) and np.isfinite(seconds).all()
