"""Plots write non-empty PNG and SVG files, refuse to overwrite, and reject what they cannot draw."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from chainspace.errors import OutputExistsError, TrackError
from chainspace.view.plots import convergence_notes, plot_convergence, plot_error_sweep, plot_joint_angles, plot_joint_errors

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _check(path, kind):
    data = path.read_bytes()
    assert len(data) > 2000
    if kind == "png":
        assert data.startswith(PNG_MAGIC)
    else:
        assert b"<svg" in data[:2000] and data.rstrip().endswith(b"</svg>")


@pytest.mark.parametrize("kind", ["png", "svg"])
def test_convergence(tmp_path, kind):
    rec = SimpleNamespace(history={"kcs": {"reprojection": list(np.geomspace(20, 2, 15)),
                                           "error_3d": list(np.geomspace(0.2, 0.05, 15))},
                                   "refine": {"reprojection": [2.0, 1.0, 0.8]}})
    _check(plot_convergence(rec, tmp_path / f"c.{kind}"), kind)
    with pytest.raises(OutputExistsError):
        plot_convergence(rec, tmp_path / f"c.{kind}")


def test_convergence_says_what_its_curves_are(tmp_path):
    """The refinement's reprojection may rise above the KCS stage's (it trades it for constant bones): the
    plot draws its objective and says which stage was kept on what score, and the robot fit's level."""
    rec = SimpleNamespace(history={"kcs": {"reprojection": [40.0, 1.0, 0.2]},
                                   "refine": {"reprojection": [1.1, 1.3, 1.3], "objective": [5.0, 2.0, 1.0, 0.9]},
                                   "selection": {"kcs": [0.0229, 0.0007, 0.0222], "refine": [0.0081, 0.0074, 0.0007],
                                                 "chosen": ["refine"]}})
    fit = SimpleNamespace(residual_px=np.array([1.0, 2.0, np.nan]), intrinsics=object())
    notes = " ".join(convergence_notes(rec, fit))
    assert "Kept: refine (track score 0.0081 = reprojection 0.0074 + bone-length variation 0.0007" in notes
    assert "kcs: 0.0229 = 0.0007 + 0.0222" in notes
    assert "Robot fit: 1.58 px RMS through its pinhole camera" in notes  # sqrt((1 + 4) / 2)
    assert "can rise while the bones settle" in notes
    _check(plot_convergence(rec, tmp_path / "c.png", fit=fit), "png")
    assert "Robot fit" not in " ".join(convergence_notes(rec))
    assert "weak-perspective cameras" not in " ".join(convergence_notes(SimpleNamespace(history={"perspective": {}})))


def test_convergence_without_history(tmp_path):
    with pytest.raises(TrackError, match="no convergence history"):
        plot_convergence(SimpleNamespace(history={}), tmp_path / "c.png")
    assert not (tmp_path / "c.png").exists()


@pytest.mark.parametrize("kind", ["png", "svg"])
def test_joint_angles_and_errors(tmp_path, kind):
    t = np.linspace(0, 3, 90)[:, None]
    truth = np.sin(t * np.arange(1, 7))
    fit = SimpleNamespace(q=truth + 0.01, joint_names=[f"joint_{i}" for i in range(1, 7)],
                          observable=np.array([1, 1, 1, 1, 1, 0], bool))
    _check(plot_joint_angles(fit, truth, tmp_path / f"q.{kind}"), kind)
    _check(plot_joint_angles(fit, None, tmp_path / f"q_only.{kind}", joints=["joint_2"]), kind)
    report = SimpleNamespace(passed=True, to_dict=lambda: {"joints": [
        {"name": f"joint_{i}", "rms_deg": 0.1 * i, "max_deg": 0.3 * i} for i in range(1, 7)]})
    _check(plot_joint_errors(report, tmp_path / f"e.{kind}"), kind)


def test_joint_angles_shape_mismatch(tmp_path):
    fit = SimpleNamespace(q=np.zeros((10, 2)), joint_names=["a", "b"])
    with pytest.raises(TrackError, match="shape"):
        plot_joint_angles(fit, np.zeros((10, 3)), tmp_path / "q.png")
    with pytest.raises(TrackError, match=r"\.png, \.svg"):
        plot_joint_angles(fit, None, tmp_path / "q.jpeg")


def test_error_sweep(tmp_path):
    rows = [{"dataset": d, "noise_px": n, "error_mm": 30 + 2 * n + (5 if d == "arm" else 0)}
            for d in ("walk", "arm") for n in (0, 2, 5, 10)]
    _check(plot_error_sweep(rows, tmp_path / "s.svg"), "svg")
    cols = {"missing": [0.0, 0.2, 0.5], "error_mm": [30.0, 33.0, 40.0]}
    _check(plot_error_sweep(cols, tmp_path / "m.png"), "png")
    with pytest.raises(TrackError, match="needs an x column"):
        plot_error_sweep([{"foo": 1, "error_mm": 2}], tmp_path / "x.png")
