"""A weak-perspective fit of close-range footage (no camera given) that misses its points as a whole
says so, flags its joints and names the options that fit the camera, in the command line's words there."""

from __future__ import annotations

import warnings

import numpy as np

from chainspace.bench.full_range import judge_joints
from chainspace.bench.robots import robot_chain
from chainspace.cli import _for_the_shell
from chainspace.reconstruction.pipeline import reconstruct
from chainspace.robot.fit import PERSPECTIVE_HINT, fit_joint_angles
from chainspace.robot.uncertainty import CAMERA_MISFIT_RATIO, camera_misfit
from chainspace.synthetic.robot import synthesize


def test_camera_misfit_is_about_one_for_residuals_of_the_tracks_jitter():
    rng = np.random.default_rng(0)
    rn = np.linalg.norm(rng.normal(0.0, 1.5, (400, 8, 2)), axis=-1)  # a right model on 1.5 px tracks
    w = np.ones(rn.shape)
    ratio, typical = camera_misfit(rn, w, 1.5)
    assert abs(ratio - 1.0) < 0.05 and abs(typical - 1.5 * np.sqrt(2 * np.log(2))) < 0.1
    assert camera_misfit(2 * rn, w, 1.5)[0] > CAMERA_MISFIT_RATIO  # every point twice as far off
    assert np.isnan(camera_misfit(rn, w, float("nan"))[0])


def test_close_footage_fitted_without_its_camera_is_flagged_not_silent():
    """The milling arm through synthesize's phone-like camera, 60 frames, seed 0, fitted as a user without
    the camera would: before the whole-fit rule two of its joints were 10.8 degrees off unflagged."""
    chain = robot_chain("milling arm")
    fits, trials = {}, {}
    for camera in ("pinhole", "static"):  # a lens 1.5-4 reaches away, and weak perspective
        trials[camera] = trial = synthesize(chain, n_frames=60, noise_px=1.0, seed=0, camera=camera)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fits[camera] = fit_joint_angles(reconstruct(trial.tracks, chain, seed=0))
    close, far = fits["pinhole"], fits["static"]
    assert "times what the tracks' own jitter" in close.message and PERSPECTIVE_HINT in close.message
    verdicts = [j["verdict"] for j in judge_joints(close, trials["pinhole"])]
    assert "silent" not in verdicts and verdicts.count("flagged") >= 4, verdicts
    assert "poor fit: " not in far.message and PERSPECTIVE_HINT not in far.message


def test_the_hint_in_the_command_lines_words():
    shell = _for_the_shell("poor fit: joint_a1: ...; " + PERSPECTIVE_HINT)
    assert "--intrinsics FILE" in shell and "--image-size W H" in shell and "--perspective" in shell
    assert "=" not in shell.split("poor fit: ")[1].replace("joint_a1: ...", "")  # no Python advice left
    assert "intrinsics=" not in shell and "image_size=" not in shell
