"""Validation reports: joint errors in degrees, wrapped angles, relative joints, thresholds."""

from pathlib import Path

import json
import numpy as np
import pytest

from chainspace.errors import ChainspaceError
from chainspace.robot.fit import fit_joint_angles
from chainspace.synthetic.robot import synthesize
from chainspace.io.urdf import from_urdf
from chainspace.robot.validation import validate

URDF = Path(__file__).resolve().parents[1] / "robots" / "milling_arm.urdf"


@pytest.fixture(scope="module")
def fitted():
    chain = from_urdf(URDF)
    t = synthesize(chain, n_frames=20, noise_px=0.0, seed=11, camera="static")
    return t, fit_joint_angles(t.positions, chain=chain, transform="none")


def test_exact_fit_passes(fitted):
    t, fit = fitted
    rep = validate(fit, t.q)
    assert rep.passed
    assert all(j["rms"] < 1e-4 for j in rep.joints)
    assert rep.error_3d_mm < 1e-3
    assert all(abs(b["error_pct"]) < 1e-6 for b in rep.bones)  # the points were the URDF's own
    d = json.loads(json.dumps(rep.to_dict()))
    assert d["passed"] is True and len(d["joints"]) == len(fit.joint_names)
    assert "| joint_a1 |" in rep.table() and "PASSED" in rep.table()


def test_known_errors_in_degrees_and_wrapping(fitted):
    t, fit = fitted
    truth = t.q.copy()
    truth[:, 1] += np.radians(2.0)  # 2 degrees off on A2
    truth[:, 3] += 2 * np.pi  # a whole turn is the same pose
    rep = validate(fit, truth)
    rows = {j["name"]: j for j in rep.joints}
    assert rows["joint_a2"]["rms"] == pytest.approx(2.0, abs=1e-4)
    assert rows["joint_a2"]["max"] == pytest.approx(2.0, abs=1e-4)
    assert rows["joint_a4"]["rms"] < 1e-4
    assert not rep.passed and "joint_a2" in rep.message
    assert validate(fit, truth, thresholds={"joint_rms_deg": 2.5}).checks["joint_rms_deg"]


def test_relative_joint_compared_up_to_offset(fitted):
    t, fit = fitted
    fit_rel = type(fit)(**{**fit.__dict__, "relative": np.array([True] + [False] * 5),
                           "observable": np.array([False] + [True] * 5)})
    truth = t.q.copy()
    truth[:, 0] += 0.7  # a constant offset on a joint seen only relative to the first frame
    rep = validate(fit_rel, truth)
    row = rep.joints[0]
    assert row["status"] == "relative to frame 0" and row["rms"] < 1e-4


def test_bad_input(fitted):
    t, fit = fitted
    with pytest.raises(ChainspaceError):
        validate(fit, t.q[:5])
    with pytest.raises(ChainspaceError):
        validate(fit, t.q, thresholds={"speed": 1})
    with pytest.raises(ChainspaceError):
        validate("not a fit")


def test_each_flagged_joint_gets_its_own_reason(fitted):
    # the fit keeps one reason per joint (tied with another motion, not explained by the fit, or too
    # uncertain); validate gives each flagged joint its own, whatever the message says
    t, fit = fitted
    amb = np.array([True, True, False, True, False, True])
    reasons = ["poor fit: the tracks of base are fitted 3.0 times further off", "poor fit: the tracks of base", "",
               "tie: 1 other motion(s) fit the tracks as well and differ here by up to 180 deg RMS",
               "", "uncertain: standard deviation 2.4 deg (RMS over the frames, fit.q_std)"]
    flagged = type(fit)(**{**fit.__dict__, "ambiguous": amb, "joint_reasons": reasons,
                           "message": "converged; ambiguous: joint_a6 (180 deg RMS)"})
    rows = {j["name"]: j for j in validate(flagged, t.q).joints}
    assert [rows[n]["status"] for n in ("joint_a1", "joint_a3", "joint_a4")] == ["ambiguous", "observable", "ambiguous"]
    assert [rows[n].get("reason") for n in fit.joint_names] == [r if a else None for r, a in zip(reasons, amb)]
    assert not rows["joint_a1"]["judged"] and rows["joint_a3"]["judged"]
    table, summary = validate(flagged, t.q).table(), flagged.summary().splitlines()
    assert all(r in table for r in reasons) and summary[5].startswith("joint_a6: ambiguous") and reasons[5] in summary[5]
    # a fit saved before the reasons were kept per joint: its message, for each flagged joint
    old = type(fit)(**{**flagged.__dict__, "joint_reasons": []})
    assert {j.get("reason") for j in validate(old, t.q).joints if j["status"] == "ambiguous"} == {old.message}


@pytest.mark.parametrize("field", ["ambiguous", "relative", "joint_reasons"])
def test_per_joint_fields_of_the_wrong_length_are_a_clear_error(fitted, tmp_path, field):
    # read one per joint, flags for 5 of 6 joints would mark the wrong joints: refused, naming the field
    from chainspace.errors import TrackError
    from chainspace.io.results import save_results

    t, fit = fitted
    n = len(fit.joint_names)
    value = [""] * (n - 1) if field == "joint_reasons" else np.ones(n - 1, bool)
    bad = type(fit)(**{**fit.__dict__, field: value})
    with pytest.raises(TrackError, match=f"{field}.*{n - 1}.*{n} joints"):
        validate(bad, t.q)
    with pytest.raises(TrackError, match=field):
        save_results(bad, tmp_path / "fit")
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.fixture(scope="module")
def from_tracks():
    """The milling arm filmed by synthesize's default pinhole camera, 40 frames, 1 px: fitted with its
    intrinsics (the right model) and as weak perspective (the wrong one)."""
    import warnings

    from chainspace.io.descriptions import load_chain
    from chainspace.reconstruction.pipeline import reconstruct

    chain = load_chain(str(Path(__file__).resolve().parents[1] / "robots" / "milling_arm.urdf"))
    trial = synthesize(chain, n_frames=40, noise_px=1.0, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(trial.tracks, chain, seed=1)
        right = fit_joint_angles(rec, intrinsics=trial.intrinsics)
        wrong = fit_joint_angles(rec)
    return trial, right, wrong


def test_without_a_truth_the_tracks_judge_and_the_reconstruction_is_not_an_error(from_tracks):
    """No truth: a fit that explains its tracks passes, however far the monocular reconstruction lies
    from it (that distance is reported, not judged), and a fit of the wrong camera model fails."""
    trial, right, wrong = from_tracks
    rep = validate(right)
    assert rep.passed and set(rep.checks) == {"tracks_misfit"} and rep.tracks_misfit < 1.1
    assert rep.error_3d_mm is None and rep.distance_to_reconstruction_mm > 10  # the reconstruction's own error
    assert validate(right, trial.q).passed  # and the truth agrees
    assert "not judged" in rep.table() and "tracks_misfit" in rep.to_dict()
    bad = validate(wrong)
    assert not bad.passed and bad.tracks_misfit > 1.25 and "tracks_misfit <= 1.25: FAIL" in bad.table()
    assert "poor fit" in wrong.message  # as the fit itself says
    assert validate(wrong, thresholds={"tracks_misfit": float("inf")}).checks == {}


def test_a_fit_of_3d_points_alone_is_judged_on_them(fitted):
    """Fitted to 3D points (motion capture) and no truth: the distance to those points is the 3D error."""
    _, fit = fitted
    rep = validate(fit)
    assert "error_3d_pct_reach" in rep.checks and rep.tracks_misfit is None and rep.distance_to_reconstruction_mm is None


def test_deviations_that_understate_the_errors_are_called_a_lower_bound(fitted):
    """With a truth, joints whose true values lie mostly outside the reported deviations (the demo's rendered
    markers: 0 % within one) get a line saying what the deviations assume; honest ones do not."""
    t, fit = fitted
    F, nv = fit.q.shape
    narrow = type(fit)(**{**fit.__dict__, "q_std": np.full((F, nv), 1e-9)})
    truth = t.q + np.radians(0.2)  # 0.2 degrees off everywhere, a billionth of a radian reported
    assert "read them as a lower bound" in validate(narrow, truth).table()
    wide = type(fit)(**{**fit.__dict__, "q_std": np.full((F, nv), np.radians(1.0))})
    assert "lower bound" not in validate(wide, truth).table()
