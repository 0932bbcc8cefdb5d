"""Issue 21, target 1 (no silent failure): the perspective fit's PnP camera start, the wrist's exact
twins as alternatives, and the poor-fit flag for tracked points the fit misses."""

from pathlib import Path

import numpy as np
import pytest

from chainspace.io.urdf import from_urdf
from chainspace.robot.kinematics import RobotKinematics, _random_q
from chainspace.robot.perspective import _in_front, _pnp_camera
from chainspace.robot.uncertainty import POOR_FIT_RATIO, POOR_FIT_WINDOW, POOR_FIT_WINDOW_RATIO, _wrist_twins, \
    poor_fit_joints, track_jitter
from chainspace.synthetic.robot import synthesize

ROBOTS = Path(__file__).resolve().parents[1] / "robots"


@pytest.fixture(scope="module")
def arm():
    chain = from_urdf(ROBOTS / "milling_arm.urdf")
    return chain, RobotKinematics(chain.metadata["urdf_path"], chain)


def _turn(d: np.ndarray) -> np.ndarray:
    return np.abs((d + np.pi) % (2 * np.pi) - np.pi)


def test_a_wrist_twin_puts_every_tracked_point_where_the_motion_does(arm):
    chain, robot = arm
    F = 6
    q = _random_q(robot, np.random.default_rng(0), F)
    twins = _wrist_twins(robot, q, np.ones((F, robot.nv), bool))
    assert len(twins) >= 1
    for t in twins:
        assert np.abs(robot.positions(t) - robot.positions(q)).max() < 1e-9  # every point in place
        d = _turn(robot.angles(t) - robot.angles(q))
        assert d[:, :3].max() < 1e-9 and d[:, 3].min() > np.pi / 2  # the arm stays, the wrist turns over
        assert (robot.clip(t) == t).all()  # within the limits
    held = np.ones((F, robot.nv), bool)
    held[:, 4] = False  # the wrist's middle joint held: no twin may move it
    assert _wrist_twins(robot, q, held) == []


def test_a_point_the_fit_misses_in_most_frames_flags_the_joints_that_move_it(arm):
    chain, robot = arm
    rng = np.random.default_rng(1)
    F, J = 40, len(chain.joints)
    q = _random_q(robot, rng, F)
    w = np.ones((F, J))
    rn = np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)  # residual lengths of 1 px noise per coordinate
    joints, points, ratio = poor_fit_joints(robot, q, rn, w, 1.0)
    assert not joints.any() and points == [] and ratio.max() < POOR_FIT_WINDOW_RATIO
    tip = J - 1
    rn[:, tip] += 4.0  # a wrong basin: the tip 4 px off in every frame
    rn[:3, 2] += 50.0  # a few outlying detections of another point are no poor fit
    joints, points, ratio = poor_fit_joints(robot, q, rn, w, 1.0)
    assert points == [chain.joints[tip]] and ratio[tip] > POOR_FIT_RATIO
    moves = np.linalg.norm(robot.jacobians(q[::8])[1][:, tip], axis=1).max(0) > 1e-9
    assert moves.any() and joints.tolist() == moves.tolist()
    base = chain.joints.index(chain.root)
    rn[:, base] += 4.0  # the base missed too: the camera is off, and with it every joint
    assert poor_fit_joints(robot, q, rn, w, 1.0)[0].all()
    # noise-free tracks: the measured noise and the residuals are rounding, and their ratio says nothing
    tiny = 1e-12 * np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)
    tiny[:, tip] *= 5.0
    assert poor_fit_joints(robot, q, tiny, w, 1e-12)[0].any()  # without the floor: flagged
    assert not poor_fit_joints(robot, q, tiny, w, 1e-12, extent=500.0)[0].any()


def test_points_missed_on_two_legs_put_every_joint_in_doubt():
    """No one joint moves points on two legs of a quadruped: one wrong path does not explain them both, a
    wrong camera does, and then a leg that fits its own tracks is not known either (the Solo12 through a weak
    camera from above, full ranges, seed 85: two legs missed, the front right leg 79-121 degrees off and
    reported observable). Points missed on one leg flag that leg only."""
    from chainspace.bench.full_range import full_range_chain

    chain = full_range_chain("solo12")
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    rng = np.random.default_rng(3)
    F, J = 30, len(chain.joints)
    q = _random_q(robot, rng, F)
    w = np.ones((F, J))
    rn = np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)
    rn[:, chain.joints.index("FL_FOOT")] += 6.0
    joints = poor_fit_joints(robot, q, rn, w, 1.0)[0]
    legs = [n[:2] for n in robot.joint_names]
    assert [legs[k] for k in np.flatnonzero(joints)] == ["FL"] * 3  # one leg: its own joints
    rn[:, chain.joints.index("HL_FOOT")] += 6.0
    assert poor_fit_joints(robot, q, rn, w, 1.0)[0].all()  # two legs: every joint


def test_a_point_missed_over_the_last_frames_only_flags_the_joints_that_move_it(arm):
    """A path that leaves the true one for the last few frames misses a point there and nowhere else: its
    median over the sequence is the noise's (the Solo12 through a pinhole camera from below, seed 58, the
    right leg 2-55 degrees off over the last 8 of 30 frames, reported observable). Three outlying
    detections in a row are no such path."""
    chain, robot = arm
    rng = np.random.default_rng(2)
    F, J = 30, len(chain.joints)
    q = _random_q(robot, rng, F)
    w = np.ones((F, J))
    rn = np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)
    tip = J - 1
    rn[:3, 2] += 50.0  # three outliers in a row
    rn[-POOR_FIT_WINDOW:, tip] += np.linspace(2.0, 8.0, POOR_FIT_WINDOW)  # drifting off over the last frames
    joints, points, ratio = poor_fit_joints(robot, q, rn, w, 1.0)
    assert np.median(rn[:, tip]) < POOR_FIT_RATIO * np.sqrt(2 * np.log(2))  # the sequence's median sees nothing
    assert points == [chain.joints[tip]] and ratio[tip] > POOR_FIT_WINDOW_RATIO
    moves = np.linalg.norm(robot.jacobians(q[::8])[1][:, tip], axis=1).max(0) > 1e-9
    assert joints.tolist() == moves.tolist()
    rn[-POOR_FIT_WINDOW:, tip] -= np.linspace(2.0, 8.0, POOR_FIT_WINDOW)
    rn[-3:, tip] += 8.0  # only the last three frames: too few to tell from outliers
    assert poor_fit_joints(robot, q, rn, w, 1.0)[1] == []


def test_a_base_point_missed_on_average_puts_every_joint_in_doubt(arm):
    """A base point's image is one pixel in every frame: the median of thirty sightings pins it down to a
    fifth of the noise, so a fit 1.4 px off it (the TALOS arm through a pinhole camera from above, seed 61)
    has its camera placed wrong, though no residual is long."""
    from chainspace.robot.uncertainty import BASE_OFFSET_Z, base_offsets

    class Ortho:  # a static orthographic camera, 100 px per metre
        per_frame = False

        def apply(self, pos):
            return 100.0 * pos[..., :2], None

    chain, robot = arm
    rng = np.random.default_rng(5)
    F, J = 30, len(chain.joints)
    q = _random_q(robot, rng, F)
    tracks = Ortho().apply(robot.positions(q))[0] + rng.normal(size=(F, J, 2))
    w = np.ones((F, J))
    base = chain.joints.index(chain.root)
    # on the base, or on the first joint's axis
    still = ~(np.linalg.norm(robot.jacobians(q[::6])[1], axis=2).max(0) > 1e-9).any(1)
    assert still[base]
    missed, offset, z = base_offsets(robot, q, Ortho(), tracks, w, 1.0)
    assert not missed.any() and (z[still] < BASE_OFFSET_Z).all() and (offset[still] > 0).all()
    assert (offset[~still] == 0).all()  # moving points are not judged here
    shifted = tracks.copy()
    shifted[:, base] += [1.4, 0.0]
    missed, offset, z = base_offsets(robot, q, Ortho(), shifted, w, 1.0)
    assert missed.tolist() == (np.arange(J) == base).tolist() and z[base] > BASE_OFFSET_Z
    assert not base_offsets(robot, q, Ortho(), shifted, w, 1.0, extent=5000.0)[0].any()  # under the floor
    tip = J - 1
    shifted[:, tip] += [5.0, 0.0]  # a moving point off on average: the length rules' to judge
    assert base_offsets(robot, q, Ortho(), shifted, w, 1.0)[0].tolist() == missed.tolist()
    Ortho.per_frame = True  # a camera per frame: a base point's image moves, nothing is judged
    assert not base_offsets(robot, q, Ortho(), shifted, w, 1.0)[0].any()


def test_a_pinhole_fit_whose_camera_misses_a_base_point_flags_every_joint(example_urdf):
    """The TALOS arm through a pinhole camera from above over its full ranges (`bench_full_range.py`, a
    fresh seed of stop 54): arm_left_2 19 degrees off reported observable, arm_left_3 177 off, the fit's
    squared residuals 861 px^2 against the true motion's 863 (a tie the searches did not reach); its second
    base point fitted 1.4 px off the mean of its sightings, 7 standard errors of it."""
    example_urdf("talos_arm")
    judged = _judged("talos_arm", "full, above", 61, camera="pinhole")
    assert not [j for j in judged if j["verdict"] == "silent"], judged
    assert all(j["status"] == "ambiguous" for j in judged if j["status"] != "not observable"), judged
    assert all(j["reason"].startswith("ambiguous (poor fit: the base point(s)") for j in judged
               if j["verdict"] == "flagged" and j["status"] != "not observable"), judged


def test_a_point_missed_in_the_middle_of_the_arm_flags_the_joints_beyond_it_too(arm):
    # they turn their links relative to a parent the fit placed wrong
    chain, robot = arm
    rng = np.random.default_rng(2)
    F, J = 40, len(chain.joints)
    q = _random_q(robot, rng, F)
    rn = np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)
    moves = np.linalg.norm(robot.jacobians(q[::8])[1], axis=2).max(0) > 1e-9  # (J, nv)
    mid = next(j for j in range(J) if 1 < moves[j].sum() < moves.any(0).sum())  # some joints move it, not all
    rn[:, mid] += 4.0
    joints, points, _ = poor_fit_joints(robot, q, rn, np.ones((F, J)), 1.0)
    assert points == [chain.joints[mid]]
    beyond = moves.any(0) & ~moves[mid]
    assert beyond.any() and joints[beyond].all()  # the joints that do not move the missed point
    assert joints.tolist() == moves.any(0).tolist()  # a serial arm: every joint, up to it and beyond it


def test_a_fit_that_misses_every_point_is_judged_by_the_tracks_own_jitter(arm):
    chain, robot = arm
    trial = synthesize(chain, n_frames=60, noise_px=1.0, seed=3)
    w = np.isfinite(trial.tracks).all(-1).astype(float)
    assert 0.9 < track_jitter(trial.tracks, w) < 1.3  # 1 px of noise on a smooth motion
    assert np.isnan(track_jitter(trial.tracks[:2], w[:2]))
    rng = np.random.default_rng(4)
    F, J = trial.tracks.shape[:2]
    # a wrong basin that misses every point by some 50-100 px: the noise measured from these residuals
    # is as large, and no point stands out from the typical one
    rn = rng.uniform(50.0, 100.0, size=J) + np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)
    measured = float(np.median(rn)) / 1.1774
    assert not poor_fit_joints(robot, trial.q, rn, w, measured)[0].any()
    joints, points, ratio = poor_fit_joints(robot, trial.q, rn, w, measured, jitter=track_jitter(trial.tracks, w))
    assert joints.all() and len(points) == J and ratio.min() > POOR_FIT_RATIO
    # a good fit of the same tracks: the jitter changes nothing
    good = np.linalg.norm(rng.normal(size=(F, J, 2)), axis=-1)
    assert not poor_fit_joints(robot, trial.q, good, w, 1.0, jitter=track_jitter(trial.tracks, w))[0].any()


def test_pnp_finds_the_pinhole_camera_and_a_camera_behind_the_robot_is_refused(arm):
    chain, robot = arm
    trial = synthesize(chain, n_frames=5, noise_px=0.0, seed=3)  # the default realistic pinhole camera
    K = np.asarray(trial.intrinsics.K, float)
    tu = trial.intrinsics.undistort(trial.tracks)
    tu[..., 1] = K[1, 2] + (tu[..., 1] - K[1, 2]) * K[0, 0] / K[1, 1]  # square pixels, as the fit's
    w = np.isfinite(tu).all(-1).astype(float)
    view = _pnp_camera(trial.positions, np.nan_to_num(tu), w, K[0, 0], K[:2, 2])
    assert np.abs(view.R[0] - trial.camera_R).max() < 1e-5
    assert np.abs(view.t[0] - trial.camera_t).max() < 1e-5 * np.linalg.norm(trial.camera_t)
    assert _in_front(dict(view=view, pos=trial.positions))
    behind = view.moved(np.r_[0.0, 0.0, 0.0, 0.0, 0.0, -2 * view.t[0, 2]])  # the camera past the robot
    assert not _in_front(dict(view=behind, pos=trial.positions))


def test_the_perspective_fit_refines_the_weak_starts_that_fit_best_under_its_camera(arm, monkeypatch):
    # the weak fit's order says nothing under perspective (its mirror twins tie there): the Panda from
    # above had the true motion's start fourth, and only the first three were refined. Here the truth
    # comes last, behind three starts far off: it must be among the MAX_STARTS refined, and win
    from chainspace.robot import perspective
    from chainspace.robot.views import _camera_view

    chain, robot = arm
    F = 6
    trial = synthesize(chain, n_frames=F, noise_px=0.0, seed=5, camera="pinhole", focal_px=1450.0,
                       distance_reaches=2.0)
    tracks = trial.intrinsics.undistort(trial.tracks)
    w = np.ones(tracks.shape[:2])
    free = np.ones((F, robot.nv), bool)
    free[0, 0] = False  # the first joint: a turn of the camera imitates it

    def start(q):
        return dict(q=q, view=_camera_view(robot.positions(q), tracks, w, False), free=free, free_prior=free,
                    delta=None, gauge=np.arange(robot.nv) == 0, blind=np.zeros(robot.nv, bool), px_floor=0.0)

    off = [robot.clip(trial.q + np.r_[0.0, a, -a, 0.0, 0.0, 0.0]) for a in (0.9, -0.9, 1.3)]
    starts = [start(q) for q in off] + [start(trial.q)]
    refined: set[int] = set()

    def in_front(r):  # every refined fit passes here: note which start it came from (or was turned from)
        if "start" in r:  # (a camera stage's check has none)
            refined.add(next(k for k, s in enumerate(starts) if s is r["start"].get("turn_of", r["start"])))
        return _in_front(r)

    monkeypatch.setattr(perspective, "_in_front", in_front)
    best = perspective.refine_perspective(robot, starts, tracks, w, trial.intrinsics.K, None, None, 30.0, None,
                                          np.zeros((F, robot.nv), bool), 50, 1e-8, 1e9, False)
    assert 0 in refined and 3 in refined and len(refined) <= perspective.MAX_STARTS + 1  # + the best turned start
    d = np.abs((robot.angles(best["q"]) - robot.angles(trial.q) + np.pi) % (2 * np.pi) - np.pi)
    assert np.degrees(d[:, 1:]).max() < 0.1


@pytest.mark.parametrize("seed", [27, 39])
def test_the_pendulum_through_a_pinhole_camera_ends_on_the_truth_or_says_it_does_not_know(seed):
    # the double pendulum (one moving tracked point, on joint1's circle; its base point 35 mm off that
    # axis) filmed by synthesize's pinhole camera, the fit given the intrinsics, as bench_uncertainty does.
    # Before issue 21's fix joint1 ended 62 (seed 27: held in frame 0 by the weak fit's gauge, reported
    # relative to it) and 60 degrees RMS off (seed 39: every weak start in another basin), nothing flagged
    import warnings

    from chainspace.bench.robots import robot_chain
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles

    chain = robot_chain("double_pendulum")
    trial = synthesize(chain, n_frames=30, noise_px=1.0, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_joint_angles(reconstruct(trial.tracks, chain, seed=seed), fps=trial.fps, tracks=trial.tracks,
                               intrinsics=trial.intrinsics)
    robot = fit.kinematics()
    d = robot.wrap_angles(fit.angles - robot.angles(trial.q))
    if fit.relative[0]:  # seen only relative to frame 0: compared as its change since frame 0
        d = robot.wrap_angles(d - d[0])
    rms = float(np.degrees(np.sqrt((d[:, 0] ** 2).mean())))
    assert rms < 3.0 or fit.ambiguous[0], f"joint1 {rms:.1f} degrees RMS off, not flagged: {fit.message}"
    assert fit.fps == trial.fps  # kept, for the plots and the viewer to play the motion at


def _silent_joints(robot: str, setting: str, seed: int, search_ties: bool = True,
                   view_from: str = "above") -> list[tuple[str, float]]:
    """The joints reported observable yet more than the full-range benchmark's tolerance off (name,
    RMS error): ``robot`` filmed by a weak-perspective camera over its full ranges, 30 frames, 1 px
    (chainspace.bench.full_range, as `bench_full_range.py --camera static` films it), then fitted."""
    return [(j["name"], round(j["error"], 1)) for j in _judged(robot, setting, seed, search_ties, view_from)
            if j["verdict"] == "silent"]


def _judged(robot: str, setting: str, seed: int, search_ties: bool = True, view_from: str = "above",
            camera: str = "static") -> list[dict]:
    """:func:`_silent_joints`' fit, every joint judged (chainspace.bench.full_range.judge_joints); camera
    "static" (weak perspective) or "pinhole" (intrinsics known), as the benchmark films."""
    from chainspace.bench.full_range import _film, _fit, full_range_chain, judge_joints

    chain = full_range_chain(robot)
    trial = _film(chain, setting, camera, 30, seed)
    return judge_joints(_fit(chain, trial, seed, search_ties, view_from), trial)


@pytest.mark.parametrize("seed", [0, 2, 45])
def test_a_hanging_arm_through_a_weak_camera_ends_right_or_says_it_does_not_know(seed, example_urdf):
    """The TALOS left arm (two tracked base points on a line that no joint turns about: the camera is fixed
    only up to a turn about that line, or a turn that mirrors them in depth) filmed by a weak-perspective
    camera over its full ranges, from above, as `bench_full_range.py --camera static` films it. Before the
    search of candidates._static_line_starts: seed 0 arm_left_3 175 degrees off (the whole arm turned about
    the line), seed 2 four joints 2-40 degrees off (the base side mirrored in depth), all reported observable.
    Seed 45 (a fresh seed of stop 50): a line start won over a poor lead, itself the truth turned half a turn
    about the line (arm_left_2 57, arm_left_3 172 degrees off, reported observable) until a winning turn was
    turned in turn."""
    example_urdf("talos_arm")  # skips cleanly without example-robot-data
    silent = _silent_joints("talos_arm", "full, above", seed)
    assert not silent, silent


@pytest.mark.parametrize("robot, setting, seed", [("talos_arm", "full, below", 47)])
def test_a_fit_whose_solver_stopped_short_flags_every_joint(robot, setting, seed, example_urdf):
    """Weak-camera full-range runs (`bench_full_range.py --camera static`) whose winner's solver stopped
    before it converged, in a wrong basin: the TALOS arm from below, joints 3-7 8-33 degrees off. Such a
    fit is no minimum the tracks chose: every joint is flagged. (Stop 53's other such runs end right now:
    the TALOS arm from below, 54, since the weak fit is also smoothed from turns of its first joint; the
    Kinova from above, 55, joints 2-3 92-94 degrees off, since its fits' near twins are refined: see
    test_a_fit_of_an_arm_over_its_shoulder_is_refitted_from_its_near_twin.)"""
    from chainspace.bench.full_range import _film, _fit, full_range_chain, judge_joints

    example_urdf(robot)
    chain = full_range_chain(robot)
    trial = _film(chain, setting, "static", 30, seed)
    fit = _fit(chain, trial, seed, True, setting.rsplit(", ", 1)[1])
    judged = judge_joints(fit, trial)
    assert not [j for j in judged if j["verdict"] == "silent"], judged
    assert not fit.converged.all()  # (the case is still a stalled one)
    held = ~fit.observable & ~fit.relative  # (no tracked point moves these)
    assert all(("not converged" in why) != h for why, h in zip(fit.joint_reasons, held)), fit.joint_reasons
    # each note one fragment of the message (a pinhole fit splits the weak fit's message at "; " and keeps
    # the fragments it does not replace: a "; " inside a note left half a poor-fit note behind)
    assert not [n for n in fit.message.split("; ") if n.startswith(("the reported motion", "so the fit"))]


@pytest.mark.parametrize("setting, seed", [("full, above", 54), ("full, below", 55)])
def test_the_pendulum_through_a_weak_camera_is_also_smoothed_from_turns_of_its_first_joint(setting, seed):
    """The double pendulum (its base point 35 mm off joint1's axis: only that point tells a turn of joint1
    from a turn of the camera) through a weak camera over its full range, as `bench_full_range.py --camera
    static` films it (stop 53's fresh seeds): joint1 157 and 138 degrees off, reported observable, where
    the truth's basin fits the tracks as well. The smoothed search now also starts from views turned a
    quarter, a half and three quarters about the first joint's axis when that joint is not a gauge."""
    silent = _silent_joints("double_pendulum", setting, seed, view_from=setting.rsplit(", ", 1)[1])
    assert not silent, silent


def test_the_wider_search_reports_a_basin_two_moves_away(example_urdf):
    """`search_ties=True` shakes the runners-up too, and farther (uncertainty._runners_up, SHAKE_FAR_DEG).
    The TALOS left arm through a weak camera from below (seed 7): the true motion's basin ties with the
    winner's, one move from a runner-up and two from the winner; before, five joints 2-143 degrees off
    were reported with four of them observable, with or without the search."""
    example_urdf("talos_arm")
    silent = _silent_joints("talos_arm", "full, below", 7, search_ties=True)
    assert not silent, silent


def test_a_shoulder_twin_shows_the_same_image_once_the_camera_turns_with_it(example_urdf):
    """The Panda's joints 1-3 as (a, -b, c + pi), joint 1 held in frame 0 (seen relative to it): every
    tracked point where the motion puts it after one half turn about the base axis, so a static camera
    turned alike sees the same image (uncertainty._wrist_twins(..., moved=True)); not a twin in place."""
    from chainspace.bench.full_range import full_range_chain
    from chainspace.robot.views import similarity_align

    example_urdf("panda")
    chain = full_range_chain("panda")
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    F = 5
    a = np.tile(robot.angles(robot.q_rest), (F, 1))
    a[:, 1] = np.linspace(-0.6, 0.4, F)
    a[:, 2] = np.linspace(0.8, 1.6, F)  # away from 0: c + pi within joint 3's limits
    q = robot.from_angles(a)
    free = np.ones((F, robot.nv), bool)
    free[0, 0] = False  # the relative first joint
    twins = _wrist_twins(robot, q, free, moved=True)
    assert len(twins) >= 1
    b = robot.angles(twins[0])
    assert np.allclose(b[:, 0], a[:, 0]) and np.allclose(b[:, 1], -a[:, 1])
    p, pt = robot.positions(q), robot.positions(twins[0])
    assert np.abs(pt - p).max() > 0.05  # not the same points in place
    _, R, t = similarity_align(pt, p, scale=False)
    assert np.abs(pt @ R.T + t - p).max() < 1e-6
    assert _wrist_twins(robot, q, np.ones((F, robot.nv), bool), moved=True) == []  # joint 1 not relative


def test_a_weak_camera_fit_reports_the_shoulder_twin_of_its_answer(example_urdf):
    """The Panda over its full ranges through a weak camera from above (seed 20): the fit ended on the
    shoulder twin of the truth (joints 2 and 3 94 and 180 degrees off), the same image once the camera
    turns half a turn about the base axis, and reported both joints observable; now they are flagged."""
    example_urdf("panda")
    silent = _silent_joints("panda", "full, above", 20)
    assert not silent, silent


def test_the_arm_beyond_a_ball_like_shoulder_mirrored_in_depth_is_found_far_in_joint_space(example_urdf):
    """The Panda over its full ranges through a weak camera from above (seed 22): the fit ended on the
    truth with the arm beyond the shoulder mirrored in depth (joints 1, 3, 5 and 7 turned by up to half
    a turn), which IK started from its answer never reached; joints 1 and 5 were reported observable,
    28 and 126 degrees off. The far search (candidates._far_poses) finds the truth, 27 noise variances
    better under the motion prior, and the joints are flagged."""
    example_urdf("panda")
    silent = _silent_joints("panda", "full, above", 22)
    assert not silent, silent


def test_told_the_camera_is_below_the_fit_finds_the_mirror_image_seen_from_there(example_urdf):
    """The UR10 over its full ranges through a weak camera from below (seed 21), ``view_from="below"``:
    the truth is the exact mirror image of a motion seen from above, five joints 40-137 degrees away in
    joint space; the 3D fit of the reflected points never reached it, so the fit reported the motion
    seen from above, against the side it was told, five joints silently off. Now the mirror pose is
    searched for wherever it lies (candidates._far_poses) and the side decides."""
    example_urdf("ur10")
    silent = _silent_joints("ur10", "full, below", 21, view_from="below")
    assert not silent, silent


def test_the_mirror_of_an_arm_up_to_its_wrist_is_a_candidate(example_urdf):
    """The Kinova Gen2 over its full ranges through a weak camera from below (seed 25, a held-out seed),
    ``view_from="below"``: the truth is the mirror image of a motion seen from above, with the hand
    beyond the wrist mirrored back in depth (its points at the same depths). The whole mirror is no pose
    of the arm, so the fit reported the motion seen from above, joints 1-3 11-149 degrees off and
    reported observable. The fit now searches the mirror of the arm up to each link as well."""
    example_urdf("kinova")
    silent = _silent_joints("kinova", "full, below", 25, view_from="below")
    assert not silent, silent

def test_a_wrist_whose_middle_joint_is_bent_at_zero_has_its_twin_found(example_urdf):
    """The xArm7's wrist (joints 5-7, joint7 unseen: no tracked point moves with it): its outer axes
    line up with joint6 away from 0, so the twin sets joint6 to 2 b0 - b, not -b or pi - b. Through a
    weak camera over its full ranges (seed 27 from above, a seed first run after the change before
    this one) the fit ended on that twin, joints 5 and 6 179 and 163 degrees off, unreported."""
    from chainspace.robot.uncertainty import _twin_offsets

    chain = from_urdf(example_urdf("xarm7"))
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    F = 5
    q = _random_q(robot, np.random.default_rng(2), F)
    free = np.ones((F, robot.nv), bool)
    free[:, 6] = False  # joint7 held: unseen
    offsets = _twin_offsets(robot, robot.angles(q)[0], 4, True, 1e-6)
    assert any(min(abs(d), abs(abs(d) - np.pi)) > 0.1 for d in offsets), offsets  # not the textbook 0 or pi
    twins = [t for t in _wrist_twins(robot, q, free)
             if _turn(robot.angles(t) - robot.angles(q))[:, 5].max() > np.radians(20)]
    assert twins
    for t in twins:
        assert np.abs(robot.positions(t) - robot.positions(q)).max() < 1e-4 * robot.reach()
        assert _turn(robot.angles(t) - robot.angles(q))[:, 4].min() > np.pi - 1e-6  # joint5 half a turn

def test_the_far_search_reaches_a_motion_anywhere_in_joint_space_and_nothing_that_is_no_pose(arm):
    """candidates._far_poses from one motion to the points of another, far from it in joint space: a
    path through every frame that puts each point there, continuous (no jump between frames); points
    no pose of the robot reaches (the motion's points stretched) give nothing."""
    from chainspace.robot.candidates import _far_poses

    chain, robot = arm
    F, rng = 8, np.random.default_rng(3)
    t = np.linspace(0, 1, F)[:, None]

    def motion():
        a, b = _random_q(robot, rng, 2)
        return a + t * (b - a)

    q, q_far = motion(), motion()
    target = robot.positions(q_far)
    free = np.ones((F, robot.nv), bool)
    (path,) = _far_poses(robot, q, [target], free)
    assert np.linalg.norm(robot.positions(path) - target, axis=-1).max() < 1e-3 * robot.reach()
    assert _turn(np.diff(robot.angles(path), axis=0)).max() < _turn(np.diff(robot.angles(q_far), axis=0)).max() + 0.2
    assert _far_poses(robot, q, [1.5 * target], free) == []


@pytest.mark.parametrize("side,seed", [("above", 28), ("below", 28), ("above", 26)])
def test_a_quadruped_through_a_weak_camera_ends_right_or_says_it_does_not_know(side, seed, example_urdf):
    """Solo12 (legs hanging from a trunk whose tracked base and hips lie in one plane) over its full ranges
    through a weak camera (seeds 28, held out until this change): the fit ended on the exact depth mirror
    of the truth, all twelve joints 12-154 degrees off and reported observable (the camera side decides
    nothing for legs, and the legs' mirror lies half a turn away in joint space). The mirror through the
    trunk's plane is now searched wherever it lies (candidates._base_keeping_mirror, _far_poses). Seed 26
    from above: the fits before the motion prior were too rough for that search to reach their mirror
    (2.7 px); the smoothed winner's mirror is now searched too (selection._most_probable), each leg
    from whichever start reaches it (candidates._branches_combined)."""
    example_urdf("solo12")
    silent = _silent_joints("solo12", f"full, {side}", seed, view_from=side)
    assert not silent, silent


def test_the_base_keeping_mirror_leaves_a_trunk_or_an_arm_base_in_place(arm, example_urdf):
    """The reflection used for mirror images far in joint space keeps the tracked points that no joint
    moves where they are: the milling arm's base (on its vertical axis: the plane y = 0) and Solo12's
    trunk (base and four hips in one plane: that plane)."""
    from chainspace.bench.full_range import full_range_chain
    from chainspace.robot.candidates import SYMMETRY_MIRROR, _base_keeping_mirror
    from chainspace.robot.observability import _moves

    chain, robot = arm
    every = np.ones(len(chain.joints), bool)
    X = robot.positions(_random_q(robot, np.random.default_rng(1), 3))
    assert np.allclose(_base_keeping_mirror(robot, every)(X), X @ SYMMETRY_MIRROR)
    example_urdf("solo12")
    chain = full_range_chain("solo12")
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    static = ~_moves(robot).any(1)
    assert static.sum() >= 3
    mirror = _base_keeping_mirror(robot, np.ones(len(chain.joints), bool))
    X = robot.positions(_random_q(robot, np.random.default_rng(1), 3))
    Y = mirror(X)
    assert np.abs(Y[:, static] - X[:, static]).max() < 1e-9  # the trunk stays
    assert np.abs(Y[:, ~static] - X[:, ~static]).max() > 0.05  # the legs do not
    # a reflection: every distance kept
    d = np.linalg.norm(X[:, :, None] - X[:, None], axis=-1)
    assert np.allclose(np.linalg.norm(Y[:, :, None] - Y[:, None], axis=-1), d)


def test_a_tree_splits_into_branches_that_share_no_point(arm, example_urdf):
    """candidates._branch_groups: an arm is one branch (every joint moves its hand); a quadruped's joints
    split into its four legs, three joints each."""
    from chainspace.bench.full_range import full_range_chain
    from chainspace.robot.candidates import _branch_groups
    from chainspace.robot.observability import _moves

    _, robot = arm
    assert [g.tolist() for g in _branch_groups(_moves(robot))] == [list(range(robot.nv))]
    example_urdf("solo12")
    chain = full_range_chain("solo12")
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    groups = _branch_groups(_moves(robot))
    assert [len(g) for g in groups] == [3, 3, 3, 3]
    assert sorted(np.concatenate(groups).tolist()) == list(range(robot.nv))


@pytest.mark.parametrize("robot", ["ur10", "ur5"])
def test_a_joint_known_only_to_more_than_half_the_accuracy_claimed_is_flagged(robot, example_urdf):
    """The UR10 and UR5 from below over their full ranges through a weak camera (seed 31, first run at the end
    of the quadruped change): wrist_2 3.0 and 2.4 degrees RMS off with a reported standard deviation of
    1.3 and 1.1 degrees, reported observable. No other basin (noise-free tracks give it to 0.01 degree)
    and the deviations hold (12 noise draws of the same motion: 60 % of the errors within one); the flag
    compared one deviation with the 2 degrees claimed, so a third of such joints passed it. Now two
    (uncertainty.UNCERTAIN_SIGMAS)."""
    example_urdf(robot)
    silent = _silent_joints(robot, "full, below", 31, view_from="below")
    assert not silent, silent


# The Z1's case, since the fits are finished under the jerk prior (stop 60): joint2 2.45 degrees off (deviation
# 0.65) and no alternative within the tie tolerance, so it is silent again. Not the finish's doing: over 12 noise
# draws of this motion (fits from the truth through the same camera) joints 1-3 come out 1.4-1.6 of their
# deviations off RMS under the acceleration prior alone and 1.3-1.4 finished under the jerk prior; the draw
# seed 59 makes was flagged under the former by an alternative 1.6 degrees away that the finished fits lack.
KNOWN_SILENT = pytest.mark.xfail(strict=True, reason="Z1, pinhole, seed 59: joint2 2.45 degrees off, 3.8 of its "
                                 "deviations, no tied alternative (docs/benchmarks.md, full ranges, stop 60)")


@pytest.mark.parametrize("robot, seed, joint", [("panda", 61, "panda_joint1"),
                                                pytest.param("z1", 59, "joint2", marks=KNOWN_SILENT)])
def test_a_joint_whose_tied_alternative_and_deviation_add_up_past_the_claim_is_flagged(robot, seed, joint,
                                                                                        example_urdf):
    """Pinhole full-range runs from below (`bench_full_range.py`, fresh seeds of stop 54): the Panda's
    panda_joint1 2.09 degrees off (standard deviation 0.81, an alternative that fits as well 1.1 away), the
    Z1's joint2 2.51 off (0.66, an alternative 1.59 away), both reported observable: neither the tie (under
    2 degrees apart) nor the deviation alone (twice it under 2) passed the bar, together they do."""
    example_urdf(robot)
    judged = {j["name"]: j for j in _judged(robot, "full, below", seed, camera="pinhole")}
    assert not [j for j in judged.values() if j["verdict"] == "silent"], judged
    row = judged[joint]
    assert row["status"] == "ambiguous" and 0 < row["alternative"] <= 2 and 2 * row["std"] <= 2, row


def test_a_mirror_symmetric_arm_is_mirrored_joint_by_joint_and_an_offset_arm_is_not(arm, example_urdf):
    """candidates._mirror_signs: the milling arm's vertical and roll axes (a1, a4, a6) lie in its plane of
    symmetry and change sign in the mirror image, the pitch axes (a2, a3, a5) do not; every point of the
    mirrored motion is where the reflection puts it. The UR10's links are offset across that plane: no
    sign pattern mirrors it (the far search, candidates._far_poses, finds its mirror images)."""
    from chainspace.bench.full_range import full_range_chain
    from chainspace.robot.candidates import SYMMETRY_MIRROR, _mirror_signs, _mirrored_motion

    chain, robot = arm
    reflect = lambda X: X @ SYMMETRY_MIRROR  # noqa: E731
    assert _mirror_signs(robot, reflect).tolist() == [-1, 1, 1, -1, 1, -1]
    q = robot.continuous(_random_q(robot, np.random.default_rng(2), 12))
    mirrored = _mirrored_motion(robot, q, reflect)
    assert np.abs(robot.positions(mirrored) - reflect(robot.positions(q))).max() < 1e-9
    example_urdf("ur10")
    chain = full_range_chain("ur10")
    ur10 = RobotKinematics(chain.metadata["urdf_path"], chain)
    assert _mirror_signs(ur10, reflect) is None and _mirrored_motion(ur10, q, reflect) is None


@pytest.mark.parametrize("robot, seed, n_arm", [("milling_arm", 33, 3), ("z1", 26, 5)])
def test_told_the_camera_is_below_a_symmetric_arm_is_not_reported_seen_from_above(robot, seed, n_arm, example_urdf):
    """The milling arm over its full ranges through a weak camera from below (seed 33, a fresh seed run once
    at the end of the previous change), ``view_from="below"``: the winner under the motion prior was seen
    from above, and its mirror image, reached by a 3D fit frame by frame with the wrist on a different
    branch in different frames, smoothed to a score a hundred times higher; the first joint was reported
    50 degrees RMS off (its motion mirrored), unflagged. The mirror is now made joint by joint
    (candidates._mirrored_motion) and the side decides. The Z1 (seed 26) keeps the 3D fit's mirror as a
    candidate too: its first fits were poor (about 100 noise variances a frame), and only that path led
    to the true basin; with the exact mirror alone its five arm joints came out 3-98 degrees off (flagged).
    Here the first ``n_arm`` joints are right, not only flagged (the milling arm's wrist is a true tie)."""
    if robot != "milling_arm":
        example_urdf(robot)
    rows = _judged(robot, "full, below", seed, view_from="below")
    assert not [j for j in rows if j["verdict"] == "silent"], rows
    assert max(j["error"] for j in rows[:n_arm]) < 2.0, rows[:n_arm]


def test_a_joint_half_a_turn_away_with_the_camera_turned_is_searched_for(example_urdf):
    """The double pendulum over its full ranges through a weak camera from above (seed 33, a fresh seed run
    once at the end of the previous change): its one moving point nearly still (joint1 moves 2.6 degrees
    over 30 frames), so the static triangle of tracked points is seen alike by a camera turned the other
    way with joint1 167 degrees away, 0.2 px^2 apart; no restart shifted 20 or 60 degrees reached it, and
    joint1 was reported observable. The restarts now also turn each joint half a turn
    (uncertainty.SHAKE_TURN_DEG) and the tie is flagged."""
    example_urdf("double_pendulum")
    silent = _silent_joints("double_pendulum", "full, above", 33)
    assert not silent, silent


def test_a_nearly_symmetric_arm_through_a_pinhole_camera_is_not_left_on_its_mirror_image(example_urdf):
    """The Kinova Gen2 (links 5 mm off its plane of symmetry) from above through a pinhole camera, full ranges,
    seed 31: the fit was the true motion's near mirror image, joints 2 and 3 47 and 21 degrees off and
    reported observable, about 150 noise variances above the true motion's basin. The winner's near mirror
    image, given a camera of its own, leads there (perspective.NEAR_MIRROR, refine_perspective's
    mirror_start)."""
    example_urdf("kinova")
    rows = _judged("kinova", "full, above", 31, camera="pinhole")
    assert [r["verdict"] for r in rows[1:3]] == ["ok", "ok"], rows
    assert not [r["name"] for r in rows if r["verdict"] == "silent"], rows


def test_a_pinhole_fit_of_an_arm_filmed_from_below_does_not_lean_on_the_side_it_was_told(example_urdf):
    """The Kinova from below through a pinhole camera, full ranges, seed 48, fitted as a user would, with
    ``view_from`` left at "above": the weak fit that starts the perspective fit searched the far mirror
    images only of fits seen from the side it was told, and the perspective fit ended with joints 2 and 3
    19 and 112 degrees off, reported observable. Its starts now search them for every motion."""
    example_urdf("kinova")
    rows = _judged("kinova", "full, below", 48, camera="pinhole")
    assert [r["verdict"] for r in rows[1:3]] == ["ok", "ok"], rows
    assert not [r["name"] for r in rows if r["verdict"] == "silent"], rows


def test_an_arm_over_its_shoulder_is_a_near_twin_whose_points_lie_centimetres_apart(example_urdf):
    """The Kinova's joints 1-4 as (a, d - b, -c, e + pi), joint 1 held in frame 0 (its half turn left to the
    camera): a shoulder and elbow mirrored over the top, every point within a few per cent of the robot's
    size of the motion's after one rigid motion (its 1 cm elbow offset keeps it from being exact), so a
    start (uncertainty._near_twins), not an exact twin (uncertainty._wrist_twins)."""
    from chainspace.bench.full_range import full_range_chain
    from chainspace.robot.uncertainty import NEAR_TWIN_SIZE, _near_twins
    from chainspace.robot.views import similarity_align

    example_urdf("kinova")
    chain = full_range_chain("kinova")
    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    F = 5
    a = np.tile(np.radians([0.0, 255.0, 300.0, 100.0, 230.0, -50.0]), (F, 1))
    a[:, 1] += np.radians(np.linspace(0.0, -10.0, F))
    a[:, 2] += np.radians(np.linspace(0.0, -30.0, F))
    q = robot.from_angles(a)
    free = np.ones((F, robot.nv), bool)
    free[0, 0] = False  # the relative first joint
    twins = _near_twins(robot, q, free)
    over = [m for m in twins if np.allclose(_turn(robot.angles(m)[:, 2] + a[:, 2]), 0.0)]
    assert over, [np.degrees(robot.angles(m)[0]).round(1) for m in twins]
    b = robot.angles(over[0])
    assert np.allclose(_turn(b[:, 3] - a[:, 3] - np.pi), 0.0)  # the forearm half a turn on
    p, pt = robot.positions(q), robot.positions(over[0])
    size = float(np.ptp(p.reshape(-1, 3), axis=0).max())
    _, R, t = similarity_align(pt, p, scale=False)
    off = np.abs(pt @ R.T + t - p).max() / size
    assert 1e-3 < off < NEAR_TWIN_SIZE, off
    assert not any(np.allclose(robot.angles(m)[:, 2], b[:, 2]) for m in _wrist_twins(robot, q, free, moved=True))


@pytest.mark.parametrize("camera, side, seed", [("pinhole", "below", 67), ("static", "above", 67),
                                                ("static", "below", 67), ("static", "above", 55),
                                                ("static", "below", 81)])
def test_a_fit_of_an_arm_over_its_shoulder_is_refitted_from_its_near_twin(camera, side, seed, example_urdf):
    """The Kinova through a pinhole camera from below, full ranges, seed 67: the fit ended on the truth's
    near twin over the shoulder (joints 2-4 164, 132 and 178 degrees off; joint3 reported observable), 104
    noise variances above the truth, a basin no start reached. The winner's near twins are now refitted
    with the camera (perspective._near_twin_starts), and the truth's basin wins on the objective. Through a
    weak camera, from above and from below (stop 58's fresh seeds): joints 2 and 3 150 and 132 degrees off,
    reported observable, until the refined fits' near twins were refined too
    (weak_refine.WeakRefinement._near_twins_of_fits); and the weak fit from above, seed 55 (stop 53), whose
    solver had stopped short with joints 2-3 92-94 degrees off (flagged not converged) now ends right. From
    below, seed 81, right before, a near twin seen from the ruled-out side (never reflected, refined after the
    reflections) had taken over, joints 2-3 155 degrees off and reported observable, until such twins were
    set aside."""
    example_urdf("kinova")
    rows = _judged("kinova", f"full, {side}", seed, camera=camera, view_from=side)
    assert [r["verdict"] for r in rows[1:3]] == ["ok", "ok"], rows
    assert not [r["name"] for r in rows if r["verdict"] == "silent"], rows


def test_a_poor_pinhole_fit_of_a_redundant_arm_tries_every_searched_camera(example_urdf):
    """The xArm7 from above through a pinhole camera, full ranges, seed 44: the winner's joint1 was 53
    degrees off, reported seen relative to frame 0; on the camera search's six frames the arm's seven joints
    fit a wrong camera better than the true one, and the start from the search's best camera led back to
    the winner. A poor winner now gets a start from every distinct camera the search refined
    (perspective._searched_starts), and the truth's basin, 360 noise variances lower, wins."""
    example_urdf("xarm7")
    rows = _judged("xarm7", "full, above", 44, camera="pinhole")
    assert rows[0]["verdict"] == "ok", rows
    assert not [r["name"] for r in rows if r["verdict"] == "silent"], rows


@pytest.mark.parametrize("setting, seed", [("full, above", 45), ("full, below", 79)])
def test_a_quadruped_through_a_pinhole_camera_keeps_its_legs_on_their_branches(setting, seed, example_urdf):
    """The Solo12 through a pinhole camera, full ranges. From above, seed 45: with the perspective fit's own
    depth flips (its branch choice under the pinhole camera) cut at 15 iterations, as the weak fit's are, the
    front left leg ended 5, 34 and 32 degrees off, reported observable (candidates._depth_flips). From below,
    seed 79 (a fresh seed of stop 58): the front left hip and knee parted from the truth over the last 12
    frames, up to 39 degrees, reported observable, in a minimum 69 noise variances above the truth's, until the
    winner's paths were moved towards the sequence's ends and refitted (perspective._end_moves)."""
    example_urdf("solo12")
    rows = _judged("solo12", setting, seed, camera="pinhole")
    assert not [r["name"] for r in rows if r["verdict"] == "silent"], rows
