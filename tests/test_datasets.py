"""chainspace.io.datasets: Z-up metres, human17 mapping, bundled fallback, shared data when present."""

from __future__ import annotations

import numpy as np
import pytest

from chainspace import DescriptionError, DescriptionNotFoundError, TrackError
from chainspace.io import datasets as ds

needs_shared = pytest.mark.skipif(ds.shared_data_dir() is None, reason="../shared/data is absent")


@pytest.fixture
def no_shared(monkeypatch):
    monkeypatch.setattr(ds, "shared_data_dir", lambda: None)


def test_to_z_up_is_a_rotation_taking_y_to_z():
    I = np.eye(3)
    R = ds.to_z_up(I)  # rows: images of x, y, z
    assert np.allclose(R @ R.T, I) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(ds.to_z_up([0.0, 1.0, 0.0]), [0, 0, 1])


def test_human17_shipped_skeleton():
    h = ds.human17()
    assert h.joints == ds.HUMAN17_JOINTS and set(h.bones) == set(ds.HUMAN17_BONES)
    X = h.rest_pose
    j = h.joint_index
    assert np.allclose(X[j("pelvis")], 0)
    assert X[j("head")][2] > X[j("neck")][2] > X[j("thorax")][2] > X[j("spine")][2] > 0
    assert X[j("left_ankle")][2] < -0.8  # about 0.9 m below the pelvis
    assert X[j("left_hip")][1] > 0 > X[j("right_hip")][1]  # faces +x: left is +y
    # Left/right symmetric: mirror y and swap sides.
    for name in h.joints:
        twin = name.replace("left", "T").replace("right", "left").replace("T", "right")
        assert np.allclose(X[j(name)] * [1, -1, 1], X[j(twin)], atol=2e-6)
    femur = np.linalg.norm(X[j("left_knee")] - X[j("left_hip")])
    assert 0.35 < femur < 0.48


def test_cmu_walk_bundled(no_shared):
    P = ds.cmu_walk(35, 1)
    assert P.shape == (358, 17, 3)
    h = ds.human17()
    spread = np.ptp(h.bone_lengths(P), axis=0)
    composite = [h.bones.index(b) for b in ds.HUMAN17_COMPOSITE_BONES]
    single = np.setdiff1d(np.arange(h.n_bones), composite)
    assert spread[single].max() < 1e-6  # one CMU bone each: rigid
    assert spread[composite].max() < 0.002  # two CMU bones with a joint between: nearly rigid
    ankles = P[:, [h.joint_index("left_ankle"), h.joint_index("right_ankle")], 2]
    assert ankles.min() > 0.0 and ankles.min(axis=1).max() < 0.2  # Z is up, a foot near the floor
    assert np.all(P[:, h.joint_index("head"), 2] > P[:, h.joint_index("pelvis"), 2] + 0.5)


def test_cmu_walk_matches_cmu_positions():
    asf, amc = ds.bundled_data_dir() / "cmu" / "07.asf", ds.bundled_data_dir() / "cmu" / "07_01.amc"
    chain, P31 = ds.cmu_positions(asf, amc)
    assert P31.shape == (316, 31, 3) and chain.rest_pose[chain.joint_index("head"), 2] > 0.5
    P = ds.cmu_to_human17(P31, chain)
    assert np.array_equal(P[:, 0], P31[:, 0])
    assert np.array_equal(P[:, ds.HUMAN17_JOINTS.index("left_wrist")], P31[:, ds.CMU_JOINTS.index("lradius")])


def test_missing_data_is_reported(no_shared):
    with pytest.raises(DescriptionNotFoundError, match="35_03"):
        ds.cmu_walk(35, 3)
    with pytest.raises(DescriptionNotFoundError, match="shared data"):
        ds.cmu09_runs()
    with pytest.raises(DescriptionNotFoundError):
        ds.deepmimic_clip("jump")
    with pytest.raises(DescriptionNotFoundError):
        ds.laikago_gait()
    assert ds.cmu_trials(35) == []


def test_bad_arguments():
    with pytest.raises(DescriptionError):
        ds.cmu_walk("thirty-five", 1)
    with pytest.raises(DescriptionError, match="unknown DeepMimic clip"):
        ds.deepmimic_clip("moonwalk")
    with pytest.raises(TrackError):
        ds.cmu_to_human17(np.zeros((4, 17, 3)))


@needs_shared
def test_cmu09_runs():
    runs = ds.cmu09_runs()
    assert len(runs) == 11 and runs[0].shape == (141, 17, 3)
    h = ds.human17()
    single = [k for k, b in enumerate(h.bones) if b not in ds.HUMAN17_COMPOSITE_BONES]
    for P in runs:
        spread = np.ptp(h.bone_lengths(P), axis=0)
        assert spread[single].max() < 1e-9 and spread.max() < 0.005
        assert np.all(P[:, 10, 2] > P[:, 0, 2])  # head above pelvis: Z-up


@needs_shared
@pytest.mark.parametrize("name", ["jump", "cartwheel", "walk"])
def test_deepmimic_clip(name):
    chain, P = ds.deepmimic_clip(name)
    assert P.shape[1:] == (16, 3) and set(chain.joints) < set(ds.HUMAN17_JOINTS)
    L = chain.bone_lengths(P)
    assert np.abs(L - chain.bone_lengths(chain.rest_pose)).max() < 1e-9
    femur = L[0, chain.bones.index(("left_hip", "left_knee"))]
    assert femur == pytest.approx(1.686184 * 0.25, abs=1e-9)  # URDF offset times DeepMimic's scale
    if name == "walk":  # upright, feet close to the floor
        assert np.all(P[:, chain.joint_index("head"), 2] > 1.3)
        assert P[:, [chain.joint_index("left_ankle"), chain.joint_index("right_ankle")], 2].min() > 0.0


@needs_shared
def test_laikago_gait():
    chain, P = ds.laikago_gait()
    assert P.shape == (21, chain.n_joints, 3)
    assert np.abs(chain.bone_lengths(P) - chain.bone_lengths(chain.rest_pose)).max() < 1e-9
    toes = P[:, [chain.joint_index(f"toe{leg}") for leg in ("FR", "FL", "RR", "RL")], 2]
    # A trot: at every frame two toes are on the floor (toe spheres of radius 0.03 m), none is far up.
    assert np.all(np.sort(toes, axis=1)[:, 1] < 0.075) and toes.max() < 0.15
    assert P[:, 0, 2].min() > 0.4  # the base stands about 0.48 m high


@needs_shared
def test_human17_rest_pose_derivation_is_reproducible():
    import importlib.util
    from pathlib import Path

    tool = Path(__file__).resolve().parents[1] / "tools" / "make_human17_rest.py"
    spec = importlib.util.spec_from_file_location("make_human17_rest", tool)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    chain, used = mod.build()
    assert not any(u.startswith("35_") for u in used)  # never the evaluated subject
    assert np.abs(chain.rest_pose - ds.human17().rest_pose).max() < 2e-6
