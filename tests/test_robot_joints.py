"""Every kind of joint Pinocchio loads, end to end: continuous (the Kinova Gen2), prismatic (the milling
arm on its track), mimic (a gripper's second finger), fixed joints between tracked links; and the clear
errors for what the fit cannot use (no movable joint, nothing to track, a floating base).

Few frames (20), noise-free tracks, weak perspective: each fit takes well under a minute."""

import warnings

import numpy as np
import pytest

from chainspace.errors import DescriptionError
from chainspace.io.descriptions import shipped, shipped_path
from chainspace.io.results import save_results
from chainspace.io.urdf import from_urdf
from chainspace.reconstruction.pipeline import reconstruct
from chainspace.robot.fit import fit_joint_angles
from chainspace.robot.kinematics import RobotKinematics
from chainspace.robot.validation import validate
from chainspace.synthetic.robot import synthesize

MIMIC_URDF = """<?xml version="1.0"?>
<robot name="mimic_gripper_arm">
  <link name="base"/> <link name="upper"/> <link name="lower"/> <link name="palm"/>
  <link name="finger_left"/> <link name="finger_right"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="wrist" type="revolute"><parent link="lower"/><child link="palm"/>
    <origin xyz="0.3 0 0"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="finger_left_joint" type="prismatic"><parent link="palm"/><child link="finger_left"/>
    <origin xyz="0.1 0.02 0"/><axis xyz="0 1 0"/><limit lower="0" upper="0.05" effort="1" velocity="1"/></joint>
  <joint name="finger_right_joint" type="prismatic"><parent link="palm"/><child link="finger_right"/>
    <origin xyz="0.1 -0.02 0"/><axis xyz="0 -1 0"/><limit lower="0" upper="0.05" effort="1" velocity="1"/>
    <mimic joint="finger_left_joint" multiplier="2" offset="0"/></joint>
</robot>
"""


def _end_to_end(chain, n_frames, seed, tmp_path):
    """synthesize -> reconstruct -> fit_joint_angles -> validate -> save_results, noise-free."""
    trial = synthesize(chain, n_frames=n_frames, noise_px=0.0, seed=seed, camera="static")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = reconstruct(trial.tracks, chain, seed=seed)
        fit = fit_joint_angles(rec, chain=chain)
    report = validate(fit, truth_q=trial.q, truth_positions=trial.positions)
    paths = save_results(fit, tmp_path / "fit") + save_results(report, tmp_path / "validation")
    return trial, fit, report, paths


def _judged(report):
    return {j["name"]: j for j in report.joints if j["judged"]}


# ---------------------------------------------------------------------------- continuous joints
def test_kinova_spaces_and_angles(example_urdf):
    chain = from_urdf(example_urdf("kinova"))
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    assert (robot.nq, robot.nv) == (9, 6) and robot.continuous_v.sum() == 3
    assert robot.joint_names == [f"j2s6s200_joint_{k}" for k in range(1, 7)]
    # a continuous joint's direction marks both its (cos, sin) entries, and back
    v = robot.continuous_v
    assert robot.q_mask(v).sum() == 6 and np.array_equal(robot.v_mask(robot.q_mask(v)), v)
    a = np.random.default_rng(0).uniform(-3, 3, (5, 6))
    q = robot.from_angles(a)
    assert np.allclose(robot.positions(q), robot.positions(robot.from_angles(robot.angles(q))))
    assert np.allclose(np.hypot(q[:, robot.q_mask(v)][:, ::2], q[:, robot.q_mask(v)][:, 1::2]), 1.0)


def test_kinova_continuous_joints_end_to_end(example_urdf, tmp_path):
    chain = from_urdf(example_urdf("kinova"))
    trial, fit, report, paths = _end_to_end(chain, 20, 1, tmp_path)
    robot = fit.kinematics()
    truth_angles = robot.angles(trial.q)
    assert np.ptp(truth_angles[:, robot.continuous_v], axis=0).min() > 0.05  # the continuous joints move
    assert fit.q.shape == (20, 9) and fit.angles.shape == (20, 6) and len(fit.joint_names) == 6
    judged = _judged(report)
    # joint_1 is seen relative to frame 0 (no base marker), joints 2-3 absolutely; the wrist's tracked
    # points lie on its axes, so its Euler twin (a + pi, -b, c + pi) puts every point in the same place:
    # joints 4-6 are reported ambiguous, not judged
    assert set(judged) == {f"j2s6s200_joint_{k}" for k in (1, 2, 3)}
    assert list(fit.ambiguous) == [False, False, False, True, True, True]
    worst = max(j["rms"] for j in judged.values())
    print(f"kinova worst judged joint RMS {worst:.2e} deg over {len(judged)} joints")
    assert worst < 0.5
    csv = next(p for p in paths if p.suffix == ".csv").read_text().splitlines()
    assert csv[0].split(",") == ["frame"] + fit.joint_names  # one angle per joint, radians
    row = np.array(csv[1].split(",")[1:], float)
    assert np.allclose(row, fit.angles[0])


# ---------------------------------------------------------------------------- prismatic joints
def test_angle_differences_wrap_on_turning_joints_only():
    chain = shipped("milling_arm_on_track")
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    d = np.full((2, robot.nv), 2 * np.pi - 0.1)  # a turn less 0.1 rad, or 6.18 m on the track
    wrapped = robot.wrap_angles(d)
    assert robot.prismatic_v.sum() == 1 and robot.turns_v.sum() == robot.nv - 1
    assert np.allclose(wrapped[:, robot.turns_v], -0.1) and np.allclose(wrapped[:, robot.prismatic_v], d[0, 0])


def test_track_mounted_arm_is_shipped_with_fixed_joints_between_tracked_links():
    chain = shipped("milling_arm_on_track")
    assert shipped_path("milling_arm_on_track").name == "milling_arm_on_track.urdf"
    assert chain.joints[:4] == ("track", "track_end", "carriage", "base_link")
    assert chain.metadata["prismatic"] == ["joint_e1"]
    assert [tuple(b) for b in chain.metadata["variable_bones"]] == [("track", "carriage")]
    lengths = dict(zip(chain.links, chain.bone_lengths(chain.rest_pose)))
    assert lengths[("carriage", "base_link")] == pytest.approx(0.10)  # a fixed joint: no zero-length bone
    assert lengths[("track", "track_end")] == pytest.approx(5.0)


def test_track_mounted_arm_end_to_end(tmp_path):
    chain = shipped("milling_arm_on_track")
    trial, fit, report, _ = _end_to_end(chain, 20, 2, tmp_path)
    e1 = fit.joint_names.index("joint_e1")
    assert np.ptp(trial.q[:, e1]) > 0.2  # the carriage travels
    judged = _judged(report)
    assert judged["joint_e1"]["unit"] == "mm" and judged["joint_e1"]["rms"] < 3.0
    print("track arm: e1 RMS {:.2e} mm, worst angle {:.2e} deg".format(
        judged["joint_e1"]["rms"], max(j["rms"] for n, j in judged.items() if n != "joint_e1")))
    assert max(j["rms"] for n, j in judged.items() if n != "joint_e1") < 0.5
    # the bone across the prismatic joint has no one length: reported, not judged
    bone = next(b for b in report.bones if b["name"] == "track-carriage")
    assert bone["error_pct"] is None


# ---------------------------------------------------------------------------- mimic joints
def test_mimic_joint_is_driven_by_its_leader(tmp_path):
    path = tmp_path / "mimic_gripper.urdf"
    path.write_text(MIMIC_URDF)
    chain = from_urdf(path)
    robot = RobotKinematics(path, chain)
    assert robot.nv == 4 and "finger_right_joint" not in robot.joint_names  # not a degree of freedom
    q = robot.q_rest.copy()
    q[3] = 0.02  # open the leader: the mimic finger moves twice as far (multiplier 2)
    pos = robot.positions(q)[0]
    left, right = chain.joint_index("finger_left"), chain.joint_index("finger_right")
    assert pos[left, 1] - pos[right, 1] == pytest.approx(0.04 + 0.02 + 0.04)
    # the Jacobian of the mimic finger is folded onto the leader's column
    q2 = q.copy()
    q2[3] += 1e-6
    _, jac = robot.jacobians(q)
    assert np.allclose((robot.positions(q2)[0] - pos) / 1e-6, jac[0, :, :, 3], atol=1e-5)
    trial, fit, report, _ = _end_to_end(chain, 20, 3, tmp_path)
    judged = _judged(report)
    assert "finger_left_joint" in judged and judged["finger_left_joint"]["rms"] < 1.0  # mm
    assert max(j["rms"] for n, j in judged.items() if n != "finger_left_joint") < 0.5


# ---------------------------------------------------------------------------- clear errors
def _write(tmp_path, name, body):
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?>\n<robot name="{path.stem}">\n{body}\n</robot>\n')
    return path


def test_no_movable_joint_is_refused_naming_the_file(tmp_path):
    path = _write(tmp_path, "statue.urdf", '<link name="a"/><link name="b"/><joint name="j" type="fixed">'
                  '<parent link="a"/><child link="b"/><origin xyz="0 0 1"/></joint>')
    with pytest.raises(DescriptionError, match="no movable joint") as info:
        from_urdf(path)
    assert "statue.urdf" in str(info.value)


def test_nothing_to_track_is_refused_naming_the_file(tmp_path):
    # a turntable: the only moving link has its origin on the base's, one point after merging
    path = _write(tmp_path, "turntable.urdf", '<link name="a"/><link name="b"/><joint name="j" type="continuous">'
                  '<parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint>')
    with pytest.raises(DescriptionError, match="nothing to track") as info:
        from_urdf(path)
    assert "turntable.urdf" in str(info.value)
    with pytest.raises(DescriptionError, match="nothing to track") as info:
        from_urdf(shipped_path("milling_arm"), links=["link_3"])
    assert "milling_arm.urdf" in str(info.value)


def test_floating_base_is_refused_by_the_fit_naming_the_joint(tmp_path):
    path = _write(tmp_path, "drone_arm.urdf", '<link name="world"/><link name="body"/><link name="arm"/>'
                  '<joint name="free" type="floating"><parent link="world"/><child link="body"/></joint>'
                  '<joint name="j" type="revolute"><parent link="body"/><child link="arm"/><origin xyz="0 0 0.3"/>'
                  '<axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>')
    chain = from_urdf(path)  # a chain to reconstruct is fine
    for call in (lambda: synthesize(chain, n_frames=5), lambda: fit_joint_angles(chain.rest_pose[None], chain=chain)):
        with pytest.raises(DescriptionError, match="joint 'free' is floating.*not supported") as info:
            call()
        assert "drone_arm.urdf" in str(info.value)
    # the command line says the same before reconstructing the tracks (whose own error named the world
    # link as an untracked joint)
    from typer.testing import CliRunner

    from chainspace.cli import app
    from chainspace.io.tracks import save_tracks

    tracks = tmp_path / "t.csv"
    save_tracks(tracks, np.zeros((4, 2, 2)) + np.arange(8.0).reshape(4, 2, 1), ["body", "arm"])
    result = CliRunner().invoke(app, ["fit", str(tracks), "--urdf", str(path), "--out", str(tmp_path / "f")])
    assert result.exit_code == 2 and "joint 'free' is floating" in result.output and "world" not in result.output


# ---------------------------------------------------------------------------- batched kinematics
@pytest.mark.parametrize("urdf", ["milling_arm", "mimic", "kinova"])
def test_batched_kinematics_match_pinocchio(urdf, tmp_path, request):
    """The fit's batched forward kinematics and Jacobians (numpy over all frames) give what a loop over
    Pinocchio gives, on revolute, unaligned, prismatic, mimic and continuous joints."""
    from chainspace.robot.kinematics import _random_q

    if urdf == "mimic":
        path = tmp_path / "mimic_gripper.urdf"
        path.write_text(MIMIC_URDF)
    elif urdf == "kinova":
        path = request.getfixturevalue("example_urdf")("kinova")
    else:
        path = shipped_path(urdf)
    robot = RobotKinematics(path, from_urdf(path))
    assert robot._batch is not None
    q = _random_q(robot, np.random.default_rng(1), 50)
    pos, jac = robot.jacobians(q)
    robot._batch = None  # the Pinocchio loop
    pos_ref, jac_ref = robot.jacobians(q)
    assert np.allclose(pos, pos_ref, atol=1e-12) and np.allclose(jac, jac_ref, atol=1e-12)
    assert np.allclose(RobotKinematics(path, from_urdf(path)).positions(q), pos_ref, atol=1e-12)


def test_joints_that_move_no_tracked_point_are_left_out_of_the_kinematics(tmp_path):
    """A gripper beyond the last tracked point (the Panda's fingers): its joints are not placed and its
    Jacobian column is zero, while the tracked points and their Jacobians are Pinocchio's own."""
    import pinocchio as pin

    from chainspace.robot.kinematics import _random_q

    path = tmp_path / "mimic_gripper.urdf"
    path.write_text(MIMIC_URDF)
    robot = RobotKinematics(path, from_urdf(path, links=["base", "upper", "lower", "palm"]))
    fingers = [robot.model.getJointId(n) for n in ("finger_left_joint", "finger_right_joint")]
    assert robot._batch is not None and set(fingers).isdisjoint(robot._batch.joints)
    q = _random_q(robot, np.random.default_rng(2), 20)
    q[:, robot.model.joints[fingers[0]].idx_q] = 0.03  # open: a finger column would not be zero by accident
    placed = robot.placed(q)
    assert np.isnan(placed.R[fingers]).all()  # not placed
    pos, jac = robot.jacobians(q)
    d = robot.model.createData()
    for f in range(len(q)):
        pin.computeJointJacobians(robot.model, d, q[f])
        pin.updateFramePlacements(robot.model, d)
        for k, fid in enumerate(robot.frame_ids):
            ref = pin.getFrameJacobian(robot.model, d, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
            np.testing.assert_allclose(pos[f, k], d.oMf[fid].translation, rtol=0, atol=1e-12)
            np.testing.assert_allclose(jac[f, k], ref, rtol=0, atol=1e-12)
    assert np.abs(jac[..., :3]).max() > 0.1 and not jac[..., 3].any()  # the arm moves the points, the finger none


@pytest.mark.parametrize("urdf", ["milling_arm", "mimic"])
@pytest.mark.parametrize("loop", [False, True])
def test_jacobians_of_some_placed_frames_are_theirs(urdf, loop, tmp_path):
    """The solvers place every trial step and take the Jacobians of the steps they keep afterwards
    (RobotKinematics.placed, jacobians_of): those rows' Jacobians are the ones of the whole batch, in
    the batched kinematics and in the loop over Pinocchio."""
    from chainspace.robot.kinematics import _random_q

    if urdf == "mimic":
        path = tmp_path / "mimic_gripper.urdf"
        path.write_text(MIMIC_URDF)
    else:
        path = shipped_path(urdf)
    robot = RobotKinematics(path, from_urdf(path))
    if loop:
        robot._batch = None
    q = _random_q(robot, np.random.default_rng(3), 40)
    pos, jac = robot.jacobians(q)
    placed = robot.placed(q)
    rows = np.array([31, 2, 2, 17, 0])
    np.testing.assert_array_equal(placed.pos, pos)
    np.testing.assert_allclose(robot.jacobians_of(placed, rows), jac[rows], rtol=0, atol=1e-12)
    assert np.abs(jac[rows]).max() > 0.1  # not a comparison of zeros


def test_repeated_and_meeting_starts_are_solved_once_with_the_same_answers():
    """The solver's shortcut for independent frames: a batch that repeats rows (one start, target and
    weights twice), or whose starts meet, gives every row what solving it alone gives."""
    from chainspace.robot.kinematics import _random_q
    from chainspace.robot.solver import _sequence_lm
    from chainspace.robot.views import _View, _rotvec

    path = shipped_path("milling_arm")
    robot = RobotKinematics(path, from_urdf(path))
    rng = np.random.default_rng(2)
    truth = _random_q(robot, rng, 4)
    view = _View(np.array([500.0]), _rotvec(np.array([0.3, -0.2, 0.1]))[None], np.array([[400.0, 300.0]]),
                 np.zeros(4, int))
    u = view.apply(robot.positions(truth))[0] + rng.normal(0, 1.0, (4, robot.chain.n_joints, 2))
    w = np.ones(u.shape[:2])
    starts = np.concatenate([truth + 0.2, robot.clip(truth - 0.3)])  # two starts per frame
    rows = np.array([0, 1, 2, 3, 4, 5, 6, 7, 0, 5, 5, 2])  # some repeated
    args = (np.zeros(6, bool), 30, 1e-10, None)
    alone = [_sequence_lm(robot, starts[k:k + 1], u[k % 4][None], w[:1], view.take(np.array([0])),
                          np.ones((1, robot.nv), bool), *args) for k in range(8)]
    q, _, rn, pos, conv, _ = _sequence_lm(robot, starts[rows], u[rows % 4], w[rows % 4], view.take(rows % 4),
                                          np.ones((len(rows), robot.nv), bool), *args)
    for i, k in enumerate(rows):
        assert np.allclose(q[i], alone[k][0][0], atol=1e-5)
        assert np.allclose(rn[i], alone[k][2][0], atol=1e-3)  # px
        assert np.allclose(pos[i], robot.positions(q[i])[0], atol=1e-12)
    assert np.array_equal(q[8], q[0]) and np.array_equal(q[9], q[5]) and np.array_equal(q[10], q[5])


@pytest.mark.parametrize("compiled", [True, False])
def test_row_groups_are_np_uniques_groups_in_its_order(monkeypatch, compiled):
    """The solver's grouping of equal rows (a hash of the bytes, checked) gives np.unique's first
    occurrences, order and labels, with -0.0 and 0.0 one value as numpy compares them; rows it cannot
    hash as numbers (NaN) go to np.unique itself. In compiled code and in numpy (without numba)."""
    from chainspace.robot import solver
    from chainspace.robot.solver import _row_groups

    if not compiled:
        monkeypatch.setattr(solver, "_compiles", lambda: False)

    rng = np.random.default_rng(0)
    base = np.round(rng.normal(size=(40, 9)), 1)
    key = base[rng.integers(0, 40, 300)]
    key[::7, 3], key[::5, 3] = -0.0, 0.0
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    f, i = _row_groups(key)
    assert len(first) < len(key) and np.array_equal(f, first) and np.array_equal(i, inverse.reshape(-1))
    f, i = _row_groups(key, ordered=False)  # the same groups, each row with its group's first occurrence
    assert np.array_equal(np.sort(f), np.sort(first)) and np.array_equal(f[i], first[inverse.reshape(-1)])
    key[3, 0] = np.nan
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    f, i = _row_groups(key)
    assert np.array_equal(f, first) and np.array_equal(i, inverse.reshape(-1))
