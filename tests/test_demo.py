"""The demo end to end on a short sequence: a rendered video in, its markers found, the joint angles fitted
and validated; files written, no overwriting. Seed and length as the browser test's (one cached clip)."""

import json

import numpy as np
import pytest

from chainspace.demo import DEMO_FILES, run_demo
from chainspace.errors import OutputExistsError
from chainspace.video.reader import open_video


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    return out, run_demo(out, progress=False, seed=8, n_frames=40)


def test_demo_writes_its_files(demo):
    out, summary = demo
    for name in DEMO_FILES:
        assert (out / name).is_file(), name
    report = json.loads((out / "validation.json").read_text())
    assert report["passed"] == summary["passed"]
    assert summary["fit"].q.shape == summary["truth_q"].shape
    # the tracks file is a tracker's CSV: frame, joint, x, y, confidence
    head = (out / "tracks.csv").read_text().splitlines()[0]
    assert head.split(",")[:4] == ["frame", "joint", "x", "y"]
    # the video and its truth came with it, and the markers were found where the renderer drew them
    assert (out / "video.mp4").stat().st_size > 10_000
    assert summary["marker_error_px"]["n"] > 100 and summary["marker_error_px"]["rms"] < 0.5
    assert len(summary["markers"].seen) >= 6


def test_demo_recovers_the_milling_path(demo):
    _, summary = demo
    rep = summary["report"]
    judged = [j for j in rep.joints if j["judged"]]
    assert judged and max(j["rms"] for j in judged) < 2.0  # markers found in a rendered video, 40 frames
    assert rep.error_3d_pct_reach < 1.0


def test_the_overlay_puts_the_fitted_robot_on_the_rendered_robot(demo):
    out, summary = demo
    fit, truth = summary["fit"], np.load(out / "video.truth.npz")
    with open_video(out / "overlay.mp4") as overlay, open_video(out / "video.mp4") as video:
        assert overlay.frame_count == video.frame_count == fit.n_frames and overlay.size == video.size
        drawn, filmed = overlay.frame(0).astype(int), video.frame(0).astype(int)
    names = list(truth["point_names"])
    both = [n for n in fit.chain.joints if n in names]
    assert len(both) >= 6
    fitted = fit.reprojected()[0, [fit.chain.joint_index(n) for n in both]]
    true = truth["points"][0, [names.index(n) for n in both]]
    assert np.linalg.norm(fitted - true, axis=-1).max() < 3.0  # the fitted markers land on the rendered ones
    for x, y in np.round(fitted).astype(int):  # and the overlay drew there
        assert np.abs(drawn[y - 3:y + 4, x - 3:x + 4] - filmed[y - 3:y + 4, x - 3:x + 4]).max() > 60


def test_demo_refuses_to_overwrite(demo):
    out, _ = demo
    before = (out / "joint_angles.csv").read_bytes()
    with pytest.raises(OutputExistsError):
        run_demo(out, progress=False, n_frames=10)
    assert (out / "joint_angles.csv").read_bytes() == before
