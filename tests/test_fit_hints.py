"""A weak-perspective fit of close-range footage that fits poorly says how to fit it under perspective,
in the command line's words there."""

from __future__ import annotations

import warnings

from chainspace.bench.robots import robot_chain
from chainspace.cli import _for_the_shell
from chainspace.reconstruction.pipeline import reconstruct
from chainspace.robot.fit import PERSPECTIVE_HINT, fit_joint_angles
from chainspace.synthetic.robot import synthesize


def test_a_poor_weak_fit_of_close_footage_points_to_the_camera_options():
    chain = robot_chain("milling arm")
    fits = {}
    for camera in ("pinhole", "static"):  # synthesize's phone-like lens 1.5-4 reaches away, and weak perspective
        trial = synthesize(chain, n_frames=30, noise_px=1.0, seed=4, camera=camera)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fits[camera] = fit_joint_angles(reconstruct(trial.tracks, chain, seed=4))
    assert "poor fit: " in fits["pinhole"].message and PERSPECTIVE_HINT in fits["pinhole"].message
    assert "poor fit: " not in fits["static"].message and PERSPECTIVE_HINT not in fits["static"].message


def test_the_hint_in_the_command_lines_words():
    shell = _for_the_shell("poor fit: joint_a1: ...; " + PERSPECTIVE_HINT)
    assert "--intrinsics FILE" in shell and "--image-size W H" in shell
    assert "intrinsics=" not in shell and "image_size=" not in shell
