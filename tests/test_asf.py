"""ASF/AMC loading: CMU files bundled in chainspace/data/cmu, and small hand-made files."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from chainspace import ChainspaceError, DescriptionError, DescriptionNotFoundError, from_asf, load_amc
from chainspace.io.datasets import CMU_JOINTS, bundled_data_dir, shared_data_dir

CMU = bundled_data_dir() / "cmu"
UNIT = 0.0254 / 0.45  # metres per CMU ASF unit


@pytest.fixture(scope="module")
def chain35():
    return from_asf(CMU / "35.asf")


def test_cmu_skeleton_points_and_femur(chain35):
    assert chain35.joints == CMU_JOINTS  # root + bone ends in ASF bone-id order
    assert chain35.root == "root"
    assert ("lhipjoint", "lfemur") in chain35.bones and ("thorax", "lclavicle") in chain35.bones
    femur = np.linalg.norm(chain35.rest_pose[2] - chain35.rest_pose[1])
    assert femur == pytest.approx(7.41015 * UNIT, abs=1e-9)
    assert femur == pytest.approx(0.418, abs=0.001)


@pytest.mark.parametrize("amc, frames", [("35_01.amc", 358), ("35_02.amc", 387)])
def test_bone_lengths_constant_and_equal_to_asf(chain35, amc, frames):
    # 35_01 has CRLF line endings and starts at frame 1; 35_02 has LF and starts at frame 20.
    P = load_amc(chain35, CMU / amc)
    assert P.shape == (frames, 31, 3)
    L = chain35.bone_lengths(P)
    assert np.abs(L - chain35.bone_lengths(chain35.rest_pose)).max() < 1e-6
    femur = L[:, chain35.bones.index(("lhipjoint", "lfemur"))]
    assert np.allclose(femur, 0.418, atol=0.001)


def test_walk_is_physically_plausible(chain35):
    P = load_amc(CMU / "35.asf", CMU / "35_01.amc")  # the ASF path works too
    feet = [chain35.joint_index(n) for n in ("lfoot", "ltoes", "rfoot", "rtoes")]
    lowest = P[:, feet, 1].min(axis=1)  # Y is up in the file
    assert lowest.min() > -0.02 and lowest.max() < 0.1  # a foot is on the floor in every frame
    head = P[:, chain35.joint_index("head"), 1]
    assert np.all((head > 1.5) & (head < 1.8))
    travel = P[-1, 0] - P[0, 0]
    assert np.hypot(travel[0], travel[2]) > 2.0 and abs(travel[1]) < 0.1  # walks on the level


def _amc(values: dict[str, str], frames=(1,)) -> str:
    lines = [":FULLY-SPECIFIED", ":DEGREES"]
    for f in frames:
        lines.append(str(f))
        lines += [f"{k} {v}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


def _zero_values(chain) -> dict[str, str]:
    skel = chain.metadata["asf"]
    vals = {"root": "0 0 0 0 0 0"}
    vals.update({b.name: " ".join(["0"] * len(b.dof)) for b in skel.bones if b.dof})
    return vals


def test_zero_motion_is_the_rest_pose(chain35, tmp_path):
    f = tmp_path / "zero.amc"
    f.write_text(_amc(_zero_values(chain35), frames=(5, 6)))
    P = load_amc(chain35, f)
    assert np.allclose(P, chain35.rest_pose, atol=1e-12)


def test_knee_flexion_sign_and_angle(chain35, tmp_path):
    # CMU subjects face +z; ltibia rx = +90 deg bends the knee so the shank points backwards (-z).
    vals = _zero_values(chain35)
    vals["ltibia"] = "90"
    vals["root"] = "1 2 3 0 0 0"
    f = tmp_path / "knee.amc"
    f.write_text(_amc(vals))
    P = load_amc(chain35, f)[0]
    hip, knee, ankle = (P[chain35.joint_index(n)] for n in ("lhipjoint", "lfemur", "ltibia"))
    thigh, shank = knee - hip, ankle - knee
    cos = thigh @ shank / np.linalg.norm(thigh) / np.linalg.norm(shank)
    assert cos == pytest.approx(0.0, abs=1e-9)
    assert shank[2] < -0.4
    assert np.allclose(P[0], np.array([1, 2, 3]) * UNIT)  # root translation in metres


def test_root_rotation_turns_the_whole_body(chain35, tmp_path):
    vals = _zero_values(chain35)
    vals["root"] = "0 0 0 0 90 0"
    f = tmp_path / "turn.amc"
    f.write_text(_amc(vals))
    P = load_amc(chain35, f)[0]
    R = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=float)  # +90 deg about y
    assert np.allclose(P, chain35.rest_pose @ R.T, atol=1e-12)


# ------------------------------------------------------------------------------------------ errors
ASF_OK = (CMU / "35.asf").read_text()


def _located(exc: pytest.ExceptionInfo, path: Path, line: int | None = None) -> None:
    msg = str(exc.value)
    assert str(path) in msg
    if line is not None:
        assert re.search(rf"{re.escape(str(path))}:{line}\b", msg), msg


@pytest.mark.parametrize(
    "edit, fragment",
    [
        (lambda t: t.replace(":root", ":rooty"), ":root"),
        (lambda t: t.split(":bonedata")[0], ":bonedata"),
        (lambda t: t.replace("lfemur ltibia", "lfemur ltibiaX"), "unknown bone 'ltibiaX'"),
        (lambda t: t.replace("lhipjoint lfemur", "ltibia lfemur"), "cycle"),
        (lambda t: t.replace("length 7.41015", "length 7.4x"), "not a number"),
        (lambda t: t.replace("direction 0.34202 -0.939693 0  ", "direction 0.34202 -0.939693", 1), "3 numbers"),
        (lambda t: t.replace("    rfoot rtoes\n", ""), "'rtoes' is not attached"),
        (lambda t: t.replace("dof rx ry rz", "dof rx ry tz", 1), "not supported"),
        (lambda t: t[: t.index("name rhipjoint")], "bone block"),
    ],
)
def test_bad_asf_raises_with_location(tmp_path, edit, fragment):
    f = tmp_path / "bad.asf"
    f.write_bytes(edit(ASF_OK).encode())
    with pytest.raises(DescriptionError) as exc:
        from_asf(f)
    assert fragment in str(exc.value)
    _located(exc, f)


def test_asf_error_names_the_line(tmp_path):
    f = tmp_path / "bad.asf"
    f.write_text(ASF_OK.replace("length 7.41015", "length seven"))
    with pytest.raises(DescriptionError) as exc:
        from_asf(f)
    line = next(i for i, t in enumerate(ASF_OK.splitlines(), 1) if "length 7.41015" in t)
    _located(exc, f, line)


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(DescriptionNotFoundError):
        from_asf(tmp_path / "nope.asf")
    (tmp_path / "empty.asf").write_text("  \n")
    with pytest.raises(DescriptionError, match="empty"):
        from_asf(tmp_path / "empty.asf")
    with pytest.raises(DescriptionNotFoundError):
        load_amc(CMU / "35.asf", tmp_path / "nope.amc")


@pytest.mark.parametrize(
    "edit, fragment, line",
    [
        (lambda L: L[:-3], "truncated", 3),  # the last frame loses bones; reported at its frame line
        (lambda L: L[:5] + ["lfemurr 1 2 3"] + L[5:], "unknown bone 'lfemurr'", 6),
        (lambda L: L[:4] + ["lowerback 1 2"] + L[5:], "has 2 values", 5),
        (lambda L: L[:4] + ["lowerback 1 2 abc"] + L[5:], "'abc' is not a number", 5),
        (lambda L: L[:4] + ["lowerback 1 2 3", "lowerback 1 2 3"] + L[5:], "appears twice", 6),
        (lambda L: L[:2] + ["root 0 0 0 0 0 0"] + L[2:], "before the first frame", 3),
        (lambda L: [":DEGREES"], "no frames", None),
    ],
)
def test_bad_amc_raises_with_location(chain35, tmp_path, edit, fragment, line):
    lines = _amc(_zero_values(chain35)).splitlines()
    f = tmp_path / "bad.amc"
    f.write_text("\n".join(edit(lines)) + "\n")
    with pytest.raises(ChainspaceError) as exc:
        load_amc(chain35, f)
    assert fragment in str(exc.value)
    _located(exc, f, line)


def test_non_consecutive_frames(chain35, tmp_path):
    f = tmp_path / "gap.amc"
    f.write_text(_amc(_zero_values(chain35), frames=(1, 3)))
    with pytest.raises(DescriptionError, match="consecutive"):
        load_amc(chain35, f)


def test_chain_not_from_asf_is_refused():
    from chainspace import KinematicChain

    with pytest.raises(DescriptionError, match="from_asf"):
        load_amc(KinematicChain(["a", "b"], [("a", "b")]), CMU / "35_01.amc")


@pytest.mark.skipif(shared_data_dir() is None, reason="../shared/data is absent")
def test_every_shared_cmu_trial_loads_with_constant_bones():
    from chainspace.io.datasets import cmu_trials

    n = 0
    for subject in ("02", "07", "16", "35", "49"):
        for asf, amc in cmu_trials(subject)[:3]:  # a few per subject keeps the test short
            chain = from_asf(asf)
            L = chain.bone_lengths(load_amc(chain, amc))
            assert np.ptp(L, axis=0).max() < 1e-6
            n += 1
    assert n >= 10
