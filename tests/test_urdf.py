"""from_urdf: chains from the milling arm and example-robot-data URDFs, checked against Pinocchio."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainspace.errors import ChainspaceError, DescriptionError, DescriptionNotFoundError
from chainspace.io.urdf import from_urdf, pinocchio_model, point_positions

EXAMPLES = ["ur3", "ur5", "ur10", "panda", "xarm7", "kinova", "talos_arm", "z1", "so100", "so101",
            "baxter", "a1", "go1", "solo12"]
ROBOTS = ["milling_arm"] + EXAMPLES


@lru_cache(maxsize=None)
def _load(path: str):
    chain = from_urdf(path)
    return chain, pin.buildModelFromUrdf(path, mimic=True)  # mimic joints driven by their leader, as chainspace


@pytest.fixture(params=ROBOTS)
def robot(request, milling_arm_urdf, example_urdf):
    """(chain, Pinocchio model built independently from the same file)."""
    path = milling_arm_urdf if request.param == "milling_arm" else example_urdf(request.param)
    return _load(str(path))


def random_q(model: pin.Model, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, nq) configurations within the joint limits (unlimited angles in [-pi, pi])."""
    lo = np.maximum(model.lowerPositionLimit, -np.pi)
    hi = np.minimum(model.upperPositionLimit, np.pi)
    qs = []
    for _ in range(n):
        q = pin.neutral(model)
        for j in range(1, model.njoints):
            jm = model.joints[j]
            if jm.nq == 1:
                q[jm.idx_q] = rng.uniform(lo[jm.idx_q], hi[jm.idx_q])
            elif jm.nq == 2 and jm.nv == 1:
                a = rng.uniform(-np.pi, np.pi)
                q[jm.idx_q : jm.idx_q + 2] = np.cos(a), np.sin(a)
        qs.append(q)
    return np.array(qs)


def frame_positions(model: pin.Model, q: np.ndarray, names) -> np.ndarray:
    """Positions (J, 3) of link frames by name, straight from Pinocchio."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return np.array([data.oMf[model.getFrameId(n, pin.FrameType.BODY)].translation for n in names])


def test_points_are_pinocchio_frames_and_cover_every_link(robot):
    chain, model = robot
    for p in chain.joints:
        assert model.existFrame(p, pin.FrameType.BODY), p
    links = {f.name for f in model.frames if f.type == pin.FrameType.BODY}
    covered = set(chain.joints) | {m for ms in chain.metadata["merged"].values() for m in ms}
    assert covered == links  # nothing silently dropped
    assert chain.metadata["kind"] == "urdf"
    assert chain.metadata["joint_names"] == list(model.names[1:])
    assert chain.metadata["q_rest"].shape == (model.nq,)


def test_c_and_d_round_trip(robot, rng):
    chain, _ = robot
    X = rng.normal(size=(3, chain.n_joints))
    root = chain.joint_index(chain.root)
    np.testing.assert_allclose(X @ chain.C @ chain.D, X - X[:, [root]], atol=1e-12)


def test_rest_pose_is_pinocchio_at_q_rest(robot):
    chain, model = robot
    expected = frame_positions(model, chain.metadata["q_rest"], chain.joints)
    np.testing.assert_allclose(chain.rest_pose, expected, atol=1e-12)
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    q = chain.metadata["q_rest"]
    assert ((q >= lo - 1e-12) & (q <= hi + 1e-12)).all()


def test_bone_lengths_equal_pinocchio_frame_distances(robot, rng):
    chain, model = robot
    rest = chain.bone_lengths(chain.rest_pose)
    variable = set(chain.metadata["variable_bones"])
    fixed = [k for k, bone in enumerate(chain.links) if bone not in variable]
    for q in random_q(model, rng, 12):
        X = frame_positions(model, q, chain.joints)
        np.testing.assert_allclose(chain.bone_lengths(X)[fixed], rest[fixed], atol=1e-9)
    # only prismatic joints make a full chain's bones change length
    prismatic = {"JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned"}


    def kind(j):  # a mimic joint moves as its leader does (same q entry)
        jm = model.joints[j]
        if jm.shortname() == "JointModelMimic":
            jm = next(model.joints[k] for k in range(1, model.njoints)
                      if model.joints[k].nq and model.joints[k].idx_q == jm.idx_q)
        return jm.shortname()

    prismatic_children = {
        f.name for f in model.frames
        if f.type == pin.FrameType.BODY and kind(f.parentJoint) in prismatic
    }
    assert all(b in prismatic_children for _, b in variable)
    assert bool(variable) == bool(chain.metadata["prismatic"])


def test_merged_links_coincide_in_every_configuration(robot, rng):
    chain, model = robot
    for q in random_q(model, rng, 8):
        for point, members in chain.metadata["merged"].items():
            X = frame_positions(model, q, members)
            np.testing.assert_allclose(X, np.broadcast_to(X[0], X.shape), atol=1e-9, err_msg=point)
            assert members[0] == point


def test_point_positions_matches_pinocchio(robot, rng):
    chain, model = robot
    qs = random_q(model, rng, 4)
    got = point_positions(chain, qs.reshape(2, 2, -1))
    assert got.shape == (2, 2, chain.n_joints, 3)
    np.testing.assert_allclose(got[1, 0], frame_positions(model, qs[2], chain.joints), atol=1e-12)


# ---------------------------------------------------------------------------- the milling arm
def test_milling_arm_follows_the_datasheet(milling_arm_urdf):
    chain = from_urdf(milling_arm_urdf)
    assert chain.joints == ("base_link", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6",
                            "spindle", "tool_tip")
    assert chain.metadata["merged"] == {"link_6": ["link_6", "flange"]}
    lengths = dict(zip(chain.bones, chain.bone_lengths(chain.rest_pose)))
    for bone, metres in [(("base_link", "link_1"), 0.675), (("link_1", "link_2"), 0.350),
                         (("link_2", "link_3"), 1.150), (("link_3", "link_4"), 0.041),
                         (("link_4", "link_5"), 1.200), (("link_5", "link_6"), 0.215)]:
        assert lengths[bone] == pytest.approx(metres, abs=1e-12)
    # zero clipped into the limits: A2's range is -140..-5 degrees, so A2 rests at -5 degrees
    q = chain.metadata["q_rest"]
    assert np.degrees(q) == pytest.approx([0, -5, 0, 0, 0, 0])
    up = np.sin(np.radians(5))
    np.testing.assert_allclose(chain.rest_pose[3] - chain.rest_pose[2], 1.15 * np.array([np.cos(np.radians(5)), 0, up]), atol=1e-6)  # limits have 7 decimals
    # reach of the wrist centre from the A1 axis, arm stretched (A2 = -5 deg is the closest to flat)
    stretched = from_urdf(milling_arm_urdf, q={"joint_a3": -np.radians(5) + np.arctan2(0.041, 1.2)})
    wrist = stretched.rest_pose[stretched.joint_index("link_5")]
    assert 2.5 <= np.hypot(*wrist[:2]) <= 3.0


def test_milling_arm_has_limits_speeds_and_visuals(milling_arm_urdf):
    import yourdfpy

    urdf = yourdfpy.URDF.load(str(milling_arm_urdf), load_meshes=True)  # no mesh files are needed
    movable = [j for j in urdf.robot.joints if j.type != "fixed"]
    assert len(movable) == 6
    assert all(j.limit.lower < j.limit.upper and j.limit.velocity > 0 for j in movable)
    assert np.degrees(urdf.joint_map["joint_a1"].limit.upper) == pytest.approx(185)
    for link in urdf.robot.links:
        assert link.visuals, link.name
        for v in link.visuals:
            assert v.geometry.mesh is None and v.material is not None
    assert len(urdf.scene.geometry) >= 9


def test_extra_frames_are_tracked_points(milling_arm_urdf, rng):
    extra = {"probe": ("link_4", (0.6, 0.0, 0.15)), "flange_mark": ("flange", (0.05, 0.0, 0.0))}
    chain = from_urdf(milling_arm_urdf, extra_frames=extra)
    assert chain.joints[-2:] == ("probe", "flange_mark")
    assert ("link_4", "probe") in chain.bones and ("link_6", "flange_mark") in chain.bones
    assert chain.metadata["extra_frames"]["probe"] == ("link_4", [0.6, 0.0, 0.15])
    model = pinocchio_model(chain)
    plain = pin.buildModelFromUrdf(str(milling_arm_urdf))
    for q in random_q(plain, rng, 5):
        data = plain.createData()
        pin.framesForwardKinematics(plain, data, q)
        parent = data.oMf[plain.getFrameId("link_4", pin.FrameType.BODY)]
        got = point_positions(chain, q, model=model)
        np.testing.assert_allclose(got[chain.joint_index("probe")], parent.act(np.array([0.6, 0, 0.15])), atol=1e-12)
        np.testing.assert_allclose(chain.bone_lengths(got), chain.bone_lengths(chain.rest_pose), atol=1e-9)


def test_links_keeps_a_subset_in_the_given_order(example_urdf):
    path = example_urdf("ur5")
    full = from_urdf(path)
    chain = from_urdf(path, links=["world", "upper_arm_link", "wrist_1_link", "tool0"])
    assert chain.joints == ("world", "upper_arm_link", "wrist_1_link", "tool0")
    assert chain.bones == (("world", "upper_arm_link"), ("upper_arm_link", "wrist_1_link"), ("wrist_1_link", "tool0"))
    # tool0 is merged into ee_link: the point takes the name the user gave, at the same place
    np.testing.assert_allclose(chain.rest_pose[3], full.rest_pose[full.joint_index("ee_link")])
    assert chain.metadata["merged"]["tool0"] == ["ee_link", "tool0"]
    with pytest.raises(DescriptionError, match="'ee_link' and 'tool0'"):
        from_urdf(path, links=["world", "ee_link", "tool0"])
    with pytest.raises(DescriptionError, match="unknown link 'elbow' in links="):
        from_urdf(path, links=["world", "elbow"])


def test_q_sets_the_rest_configuration(milling_arm_urdf):
    chain = from_urdf(milling_arm_urdf, q={"joint_a2": -np.pi / 2, "joint_a3": np.pi / 2})
    rest = chain.rest_pose
    np.testing.assert_allclose(rest[3] - rest[2], [0, 0, 1.15], atol=1e-12)  # upper arm vertical
    same = from_urdf(milling_arm_urdf, q=chain.metadata["q_rest"])
    np.testing.assert_allclose(same.rest_pose, rest)
    with pytest.raises(DescriptionError, match="nq=6"):
        from_urdf(milling_arm_urdf, q=[0, 1])
    with pytest.raises(DescriptionError, match="unknown or fixed joint 'joint_a7'"):
        from_urdf(milling_arm_urdf, q={"joint_a7": 0.0})


def test_missing_meshes_do_not_matter_and_continuous_joints_work(tmp_path, rng):
    path = tmp_path / "wheel.urdf"
    path.write_text(
        """<robot name="wheel">
  <link name="base"><visual><geometry><mesh filename="package://nowhere/base.stl"/></geometry></visual></link>
  <link name="spoke"><visual><geometry><mesh filename="missing.dae"/></geometry></visual></link>
  <link name="rim"/>
  <joint name="hub" type="continuous"><parent link="base"/><child link="spoke"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 1 0"/></joint>
  <joint name="arm" type="fixed"><parent link="spoke"/><child link="rim"/><origin xyz="0.3 0 0"/></joint>
</robot>"""
    )
    chain = from_urdf(path, q={"hub": np.pi / 2})
    assert chain.joints == ("base", "spoke", "rim")
    np.testing.assert_allclose(chain.rest_pose[2], [0, 0, 0.2], atol=1e-12)  # rotated about y by 90 deg


# ---------------------------------------------------------------------------- bad URDFs
def _robot(body: str) -> str:
    return f'<?xml version="1.0"?>\n<robot name="bad">\n{body}\n</robot>\n'


LINKS3 = '  <link name="a"/>\n  <link name="b"/>\n  <link name="c"/>\n'


def _joint(name, parent, child, kind="revolute", limit='<limit lower="-1" upper="1" effort="1" velocity="1"/>'):
    return (f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>{limit}</joint>\n')


BAD_URDFS = {
    "truncated": (_robot(LINKS3 + _joint("j1", "a", "b"))[:-30], r"bad\.urdf:\d+: malformed XML"),
    "not xml": ("this is not a robot", r"bad\.urdf:1: malformed XML"),
    "not a robot": ('<?xml version="1.0"?>\n<sdf><link name="a"/></sdf>', r"bad\.urdf:2: .*<sdf>"),
    "no links": (_robot(""), "no <link>"),
    "unknown link": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint("j2", "b", "d")),
                     r"bad\.urdf:7: joint 'j2' names unknown child link 'd'"),
    "cycle": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint("j2", "b", "c") + _joint("j3", "c", "a")),
              "cycle"),
    "cycle off the root": (_robot(LINKS3 + '  <link name="r"/>\n' + _joint("j0", "r", "a") + _joint("j1", "b", "c")
                                  + _joint("j2", "c", "b")), r"bad\.urdf:\d+: .*joint 'j1'.*two|cycle"),
    "two roots": (_robot(LINKS3 + _joint("j1", "a", "b")), r"disconnected.*'a' \(line 3\), 'c' \(line 5\)"),
    "two parents": (_robot(LINKS3 + _joint("j1", "a", "c") + _joint("j2", "b", "c")),
                    r"bad\.urdf:7: link 'c' is the child of two joints \('j1' and 'j2'\)"),
    "inverted limits": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint(
        "elbow", "b", "c", limit='<limit lower="2" upper="-1" effort="1" velocity="1"/>')),
                        r"bad\.urdf:7: joint 'elbow' has inverted limits: lower 2.0 > upper -1.0"),
    "text limit": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint(
        "elbow", "b", "c", limit='<limit lower="low" upper="1" effort="1" velocity="1"/>')),
                   r"bad\.urdf:7: joint 'elbow' has a non-numeric limit"),
    "no limit": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint("wrist", "b", "c", limit="")),
                 r"revolute joint 'wrist' has no <limit>"),
    "duplicate link": (_robot(LINKS3 + '  <link name="b"/>\n' + _joint("j1", "a", "b")),
                       r"bad\.urdf:6: link 'b' is defined twice \(first at line 4\)"),
    "duplicate joint": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint("j1", "b", "c")),
                        r"bad\.urdf:7: joint 'j1' is defined twice"),
    "bad type": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint("j2", "b", "c", kind="hinge")),
                 r"joint 'j2' has type 'hinge'"),
    "self joint": (_robot(LINKS3 + _joint("j1", "a", "b") + _joint("j2", "c", "c")), r"joint 'j2' joins link 'c'"),
    "no child": (_robot(LINKS3 + '  <joint name="j1" type="fixed"><parent link="a"/></joint>\n'),
                 r"joint 'j1' has no <child"),
}


@pytest.mark.parametrize("kind", list(BAD_URDFS))
def test_bad_urdf_raises_naming_file_and_element(tmp_path, kind):
    text, message = BAD_URDFS[kind]
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    with pytest.raises(DescriptionError, match=message) as info:
        from_urdf(path)
    assert isinstance(info.value, ChainspaceError) and str(path) in str(info.value)


def test_missing_file_names_the_path(tmp_path):
    with pytest.raises(DescriptionNotFoundError, match="nothing.urdf") as info:
        from_urdf(tmp_path / "nothing.urdf")
    assert isinstance(info.value, FileNotFoundError)


@pytest.mark.parametrize(
    ("extra", "message"),
    [({"tip": ("link_9", (0, 0, 0.1))}, "unknown parent link 'link_9'"),
     ({"tip": ("link_6", (0, 0))}, "not three finite numbers"),
     ({"tip": ("link_6", (0, np.nan, 0))}, "not three finite numbers"),
     ({"tip": ("link_6", (0, 0, 0))}, "at the origin of link 'link_6'"),
     ({"spindle": ("link_6", (0, 0, 0.1))}, "name of a link"),
     ({"tip": "link_6"}, "expected .parent_link")],
)
def test_bad_extra_frames_raise(milling_arm_urdf, extra, message):
    with pytest.raises(DescriptionError, match=message):
        from_urdf(milling_arm_urdf, extra_frames=extra)


def test_prismatic_joints_are_noted(example_urdf):
    chain = from_urdf(example_urdf("panda"))
    assert chain.metadata["prismatic"] == ["panda_finger_joint1", "panda_finger_joint2"]
    assert {b for _, b in chain.metadata["variable_bones"]} == {"panda_leftfinger", "panda_rightfinger"}


def test_path_may_be_a_string(milling_arm_urdf):
    assert from_urdf(str(milling_arm_urdf)).joints == from_urdf(Path(milling_arm_urdf)).joints


# ---------------------------------------------------------------------------- fuzzing

_TOKENS = ['"', "<", ">", "/>", "-1", "nan", "inf", "1e400", " ", "link", "joint", "fixed", "prismatic",
           "floating", "continuous", "</joint>", "<link name=\"x\"/>", "&", "\x00"]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mutated_urdf_raises_only_chainspace_errors(tmp_path, milling_arm_urdf, data):
    text = milling_arm_urdf.read_text()
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.integers(0, len(text)))
        if data.draw(st.booleans()):
            text = text[:at] + text[at + data.draw(st.integers(1, 30)):]
        else:
            text = text[:at] + data.draw(st.sampled_from(_TOKENS)) + text[at:]
    path = tmp_path / "fuzz.urdf"
    path.write_text(text)
    try:
        chain = from_urdf(path)
    except ChainspaceError as exc:
        assert str(path) in str(exc)
    else:
        assert np.isfinite(chain.rest_pose).all()
