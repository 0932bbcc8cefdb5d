"""BVH: reading a hand-written file with known answers, round trips, malformed files."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from chainspace import (
    ChainspaceError,
    DescriptionError,
    DescriptionNotFoundError,
    KinematicChain,
    OutputExistsError,
    TrackError,
    from_bvh,
    load_bvh,
    save_bvh,
)
from chainspace.io.datasets import cmu_walk, human17

# An arm in centimetres: root at (0, 100, 0), upper arm 30 cm along +x, forearm 25 cm, a hand End Site.
ARM = """HIERARCHY
ROOT Shoulder
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Elbow
  {
    OFFSET 30 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Wrist
    {
      OFFSET 25 0 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 10 0 0
      }
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.04
0 100 0 0 0 0 0 0 0 0 0 0
0 100 0 90 0 0 0 0 0 0 0 0
5 100 0 0 0 0 90 0 0 0 0 90
"""


@pytest.fixture
def arm(tmp_path):
    f = tmp_path / "arm.bvh"
    f.write_text(ARM)
    return f


def test_known_answers(arm):
    chain, P, fps = load_bvh(arm, unit="cm")
    assert chain.joints == ("Shoulder", "Elbow", "Wrist", "Wrist_end")
    assert chain.bones == (("Shoulder", "Elbow"), ("Elbow", "Wrist"), ("Wrist", "Wrist_end"))
    assert fps == pytest.approx(25.0)
    assert np.allclose(chain.rest_pose, [[0, 0, 0], [0.3, 0, 0], [0.55, 0, 0], [0.65, 0, 0]])
    assert np.allclose(P[0], [[0, 1, 0], [0.3, 1, 0], [0.55, 1, 0], [0.65, 1, 0]])
    # Root turned 90 deg about z: the arm points along +y.
    assert np.allclose(P[1], [[0, 1, 0], [0, 1.3, 0], [0, 1.55, 0], [0, 1.65, 0]], atol=1e-12)
    # Elbow bent 90 deg about z, then the wrist 90 deg about y: forearm along +y, hand along -z... of
    # the forearm frame: R_z(90) R_y(90) x = R_z(90) (0, 0, -1) = (0, 0, -1).
    assert np.allclose(P[2], [[0.05, 1, 0], [0.35, 1, 0], [0.35, 1.25, 0], [0.35, 1.25, -0.1]], atol=1e-12)
    assert np.allclose(from_bvh(arm, scale=0.01).rest_pose, chain.rest_pose)


def test_default_scale_is_metres(arm):
    assert np.allclose(from_bvh(arm).rest_pose[1], [30, 0, 0])


def _rigid_walk():
    """A human17 walk whose bones keep the rest lengths (what BVH can represent exactly)."""
    h = human17()
    P = cmu_walk(35, 1)[::4]
    B = h.bone_vectors(P)
    B = B / np.linalg.norm(B, axis=-1, keepdims=True) * h.bone_lengths(h.rest_pose)[:, None]
    return h, h.poses_from_bones(B) + P[:, :1]


@pytest.mark.parametrize("unit", [None, "cm"])
def test_round_trip_positions(tmp_path, unit):
    h, Q = _rigid_walk()
    path = save_bvh(tmp_path / "walk.bvh", h, Q, 30.0, unit=unit)
    chain, P, fps = load_bvh(path, unit=unit)
    assert chain.joints == h.joints and set(chain.bones) == set(h.bones)
    assert fps == pytest.approx(30.0, rel=1e-12)
    assert np.abs(P - Q).max() < 1e-6
    # The zero-offset helpers of multi-child joints were merged back.
    assert set(chain.metadata["merged"]) == {"pelvis", "thorax"}


def test_round_trip_random_tree(tmp_path):
    rng = np.random.default_rng(1)
    joints = [f"j{i}" for i in range(9)]
    bones = [("j0", "j1"), ("j0", "j2"), ("j0", "j3"), ("j1", "j4"), ("j4", "j5"), ("j4", "j6"), ("j2", "j7"),
             ("j7", "j8")]
    rest = rng.normal(size=(9, 3))
    chain = KinematicChain(joints, bones, rest)
    lengths = chain.bone_lengths(rest)
    dirs = rng.normal(size=(20, 8, 3))
    # Opposite to the rest direction for one bone in one frame: the half-turn case.
    dirs[3, 3] = -(rest[5] - rest[4])
    B = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True) * lengths[:, None]
    Q = chain.poses_from_bones(B) + rng.normal(size=(20, 1, 3))
    back, P, _ = load_bvh(save_bvh(tmp_path / "t.bvh", chain, Q, 60))
    assert back.joints != chain.joints  # BVH lists joints depth-first ...
    assert np.abs(chain.reorder(P, back.joints) - Q).max() < 1e-6  # ... one call puts them back


def test_swing_only_rotations(tmp_path):
    # A single bone that keeps its direction gets no rotation: twist is not invented.
    chain = KinematicChain(["a", "b", "c"], [("a", "b"), ("b", "c")], [[0, 0, 0], [0, 0, 1], [0, 1, 1]])
    Q = np.array([chain.rest_pose, chain.rest_pose @ Rotation.from_euler("z", 90, degrees=True).as_matrix().T])
    path = save_bvh(tmp_path / "s.bvh", chain, Q, 10)
    rows = path.read_text().split("Frame Time:")[1].splitlines()[1:]
    values = np.array([r.split() for r in rows], dtype=float)
    assert np.allclose(values[0], 0)
    assert np.allclose(values[1, 3:6], 0)  # the root's bone a-b lies on the turning axis: no twist
    assert np.allclose(values[1, 6:9], [90, 0, 0])  # b swings its bone to c by 90 deg about z


def test_save_refuses_and_checks(tmp_path, arm):
    h, Q = _rigid_walk()
    with pytest.raises(OutputExistsError):
        save_bvh(arm, h, Q, 30)
    with pytest.raises(TrackError):
        save_bvh(tmp_path / "x.bvh", h, Q[:, :5], 30)
    bad = Q.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(TrackError, match="finite"):
        save_bvh(tmp_path / "x.bvh", h, bad, 30)
    with pytest.raises(TrackError, match="fps"):
        save_bvh(tmp_path / "x.bvh", h, Q, 0)
    assert not (tmp_path / "x.bvh").exists()


def _lines(text: str) -> list[str]:
    return text.splitlines()


@pytest.mark.parametrize(
    "edit, fragment, line",
    [
        (lambda L: L[:-1], "truncated", 25),
        (lambda L: L[:-1] + ["5 100 0 0 0 0 90 0 0 0 90"], "11 values", 26),
        (lambda L: L[:-1] + ["5 100 0 0 0 0 90 0 0 0 90 zz"], "'zz' is not a number", 26),
        (lambda L: L + ["1 2 3 4 5 6 7 8 9 10 11 12"], "more frame lines", 27),
        (lambda L: [t for t in L if t.strip() != "MOTION"], "no MOTION", None),
        (lambda L: [t.replace("Frames: 3", "Frames: three") for t in L], "frame count", 22),
        (lambda L: [t.replace("Frame Time: 0.04", "Frame Time: -1") for t in L], "frame time", 23),
        (lambda L: L[:19] + L[20:], "unclosed", None),
        (lambda L: L[:15] + L[16:], "Expected OFFSET", None),
        (lambda L: [t.replace("OFFSET 30 0 0", "OFFSET 30 0") for t in L], "Offset must be a 3-part", 8),
        (lambda L: L[:8] + ["    CHANNELS 2 Zrotation"] + L[9:], "Channel count", 9),
        (lambda L: [t.replace("Yrotation", "Wrotation") for t in L], "unknown channel", None),
        (lambda L: [t.replace("JOINT Wrist", "JOINT Elbow") for t in L], "appears twice", 10),
        (lambda L: L[1:], "starts with HIERARCHY", 1),
        (lambda L: [t.replace("Frames: 3", "Frames: 0") for t in L[:23]], "no frames", 22),
    ],
)
def test_malformed_bvh(tmp_path, edit, fragment, line):
    f = tmp_path / "bad.bvh"
    f.write_text("\n".join(edit(_lines(ARM))) + "\n")
    with pytest.raises(ChainspaceError) as exc:
        load_bvh(f)
    msg = str(exc.value)
    assert fragment in msg and str(f) in msg
    if line is not None:
        assert f"bad.bvh:{line}:" in msg, msg


def test_missing_empty_and_bad_arguments(tmp_path, arm):
    with pytest.raises(DescriptionNotFoundError):
        from_bvh(tmp_path / "none.bvh")
    (tmp_path / "e.bvh").write_text("\n")
    with pytest.raises(DescriptionError, match="empty"):
        from_bvh(tmp_path / "e.bvh")
    with pytest.raises(DescriptionError, match="scale"):
        from_bvh(arm, scale=-1)
    with pytest.raises(DescriptionError, match="unit"):
        from_bvh(arm, unit="furlong")
    with pytest.raises(DescriptionError, match="not both"):
        from_bvh(arm, unit="cm", scale=0.01)
