"""The compiled solver (chainspace.robot.compiled) gives the numpy solver's numbers."""

import numpy as np
import pytest

from chainspace.bench.robots import robot_chain
from chainspace.robot import compiled
from chainspace.robot.kinematics import RobotKinematics, _random_q
from chainspace.robot.solver import _sequence_lm
from chainspace.robot.views import _PinholeView, _View


def _robot(name):
    chain = robot_chain(name)
    return RobotKinematics(chain.metadata["urdf_path"], chain)


def _problem(robot, kind, n=400, seed=0):
    """Rows of one IK problem each: noisy tracks of random poses, starts 0.3 rad off."""
    rng = np.random.default_rng(seed)
    q_true = _random_q(robot, rng, n)
    pos = robot.positions(q_true)
    q0 = robot.from_angles(robot.angles(q_true) + 0.3 * rng.standard_normal((n, robot.nv)))
    R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    if kind == "3d":
        view = _View.identity(n)
        return q0, pos, view
    if kind == "weak":
        view = _View(np.array([500.0]), R[None], np.array([[320.0, 240.0]]), np.zeros(n, int))
    else:
        view = _PinholeView(R[None], np.array([[0.1, -0.05, 3 * robot.reach()]]), 1000.0, np.array([640.0, 360.0]),
                            np.zeros(n, int))
    return q0, view.apply(pos)[0] + rng.standard_normal(pos.shape[:2] + (2,)), view


def _solve(robot, q0, target, view, delta, use_compiled):
    robot.__dict__.pop("_compiled", None)
    if not use_compiled:
        robot._compiled = None
    assert (compiled.CompiledModel.of(robot) is not None) == use_compiled
    n = len(q0)
    return _sequence_lm(robot, q0, target, np.ones(target.shape[:2]), view, np.ones((n, robot.nv), bool),
                        np.zeros(view.n_params, bool), 30, 1e-8, delta)


@pytest.mark.parametrize("name", ["xarm7", "kinova", "panda", "ur10"])
@pytest.mark.parametrize("kind,delta", [("3d", None), ("weak", None), ("weak", 2.0), ("pinhole", 2.0)])
def test_compiled_solver_matches_numpy(name, kind, delta):
    # revolute (the xArm7), continuous joints as (cos, sin) pairs (the Kinova), a finger no point moves (the
    # Panda), points on joint axes (the UR10). Both solvers take the same steps; where the tracks leave a
    # direction flat (a point on an axis, a redundant arm seen in 2D) rounding sends a row elsewhere along
    # it, to the same cost. The xArm7's every direction is seen: there every row ends alike.
    robot = _robot(name)
    q0, target, view = _problem(robot, kind)
    a = _solve(robot, q0, target, view, delta, True)
    b = _solve(robot, q0, target, view, delta, False)
    cost_a, cost_b = (a[2] ** 2).sum(1), (b[2] ** 2).sum(1)
    assert np.mean(np.abs(cost_a - cost_b) <= 0.01 * cost_b + 1e-12) >= 0.99
    same = np.abs(a[0] - b[0]).max(1) < 1e-6
    assert same.mean() >= (1.0 if name == "xarm7" else 0.3)
    np.testing.assert_allclose(a[3][same], b[3][same], atol=1e-8)
    assert (a[4] == b[4]).mean() > 0.97
    # a fit, not noise: the residuals are those of 1 px noise (or exact 3D points)
    assert np.median(a[2]) < (1e-6 if kind == "3d" else 3.0)


def test_continuous_joint_steps_as_pinocchio():
    # the compiled step of a continuous joint turns its (cos, sin) pair as pinocchio.integrate does
    import pinocchio as pin

    robot = _robot("kinova")
    model = compiled.CompiledModel.of(robot)
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = robot.from_angles(rng.uniform(-3, 3, robot.nv))
        dv = 0.3 * rng.standard_normal(robot.nv)
        out = np.empty(robot.nq)
        compiled._integrate(q, -dv, np.ones(robot.nv, bool), model.q_of_v, model.pair, model.limited, model.lower,
                            model.upper, out)
        np.testing.assert_allclose(out, robot.clip(pin.integrate(robot.model, q, dv)), atol=1e-12)


def test_threads_split_rows_without_changing_numbers(monkeypatch):
    robot = _robot("ur10")
    q0, target, view = _problem(robot, "weak", n=1200)
    monkeypatch.setenv("CHAINSPACE_THREADS", "1")
    a = _solve(robot, q0, target, view, None, True)
    monkeypatch.setenv("CHAINSPACE_THREADS", "3")
    b = _solve(robot, q0, target, view, None, True)
    for x, y in zip(a[:5:2] + a[3:4], b[:5:2] + b[3:4]):
        np.testing.assert_array_equal(x, y)
    assert a[5] == b[5]


def test_bad_thread_count_is_a_clear_error(monkeypatch):
    from chainspace.errors import ChainspaceError

    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("CHAINSPACE_THREADS", bad)
        with pytest.raises(ChainspaceError, match="CHAINSPACE_THREADS"):
            compiled.threads()


def test_a_solver_that_cannot_compile_falls_back_to_numpy(monkeypatch):
    # numba installed but unable to compile (an LLVM or cache-folder error): a warning, then the numpy solver
    def broken():
        raise RuntimeError("no LLVM here")

    monkeypatch.setattr(compiled, "compile_now", broken)
    compiled._compiles.cache_clear()
    try:
        robot = _robot("ur10")
        with pytest.warns(RuntimeWarning, match="could not be compiled"):
            assert compiled.CompiledModel.of(robot) is None
        q0, target, view = _problem(robot, "weak", n=50)
        out = _sequence_lm(robot, q0, target, np.ones(target.shape[:2]), view, np.ones((50, robot.nv), bool),
                           np.zeros(6, bool), 30, 1e-8, None)
        assert np.median(out[2]) < 3.0
    finally:
        compiled._compiles.cache_clear()


@pytest.mark.parametrize("kind", ["weak", "pinhole"])
def test_rows_go_on_across_calls_as_in_one(monkeypatch, kind):
    # between the iterations at which met starts merge, each row keeps its normal equations and cost
    # (lm_rows' kept): cut into calls or not, every row takes the same steps, to the bit
    from chainspace.robot import solver

    robot = _robot("ur10")
    q0, target, view = _problem(robot, kind, n=300, seed=2)
    model = compiled.CompiledModel.of(robot)
    args = (np.ones(target.shape[:2]), view, np.ones((len(q0), robot.nv), bool), 30, 1e-10, 2.0, None)
    monkeypatch.setattr(solver, "MERGE_AT", ())
    whole = solver._independent_rows(model, q0, target, *args)
    monkeypatch.setattr(solver, "MERGE_AT", (1, 2, 3, 5, 8, 13, 21))
    cut = solver._independent_rows(model, q0, target, *args)
    for a, b in zip(whole[:1] + whole[2:], cut[:1] + cut[2:]):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name,smooth", [("kinova", False), ("ur10", False), ("ur10", True), ("panda", True),
                                         ("kinova", True), ("ur10", "jerk"), ("kinova", "jerk")])
@pytest.mark.parametrize("kind,delta,free_camera", [("3d", None, "all"), ("weak", None, "all"),
                                                    ("weak", 2.0, "rotation"), ("pinhole", 2.0, "all"),
                                                    ("pinhole", None, "focal"), ("pinhole", 2.0, "centre")])
def test_a_shared_camera_moves_with_the_joints_as_in_numpy(name, smooth, kind, delta, free_camera):
    # lm_shared: every frame's joints and one camera free (the Schur complement's steps), from a camera
    # turned 3 degrees and moved off the truth; the numpy solver's costs, iterations and camera. Smooth:
    # with the motion prior (_smooth_lm: a banded step), some joints held in some frames and some joints
    # beyond their last sighting (the prior's speed term); "jerk": the jerk prior (a frame coupled to three on)
    from dataclasses import replace

    from chainspace.robot.solver import _jerk_prior, _motion_prior, _prior_band, _smooth_lm
    from chainspace.robot.views import _rotvec

    robot = _robot(name)
    q0, target, view = _problem(robot, kind, n=60, seed=3)
    turn = _rotvec(np.array([0.04, -0.03, 0.02]))[None]
    if kind == "pinhole":
        view = replace(view, R=turn @ view.R, t=view.t + 0.02, f=view.f * (1.03 if free_camera != "all" else 1.0),
                       fit_focal=free_camera != "all", fit_centre=free_camera == "centre")
    else:
        view = _View(view.S * 1.03, turn @ view.R, view.T + 0.01, view.cam_of)
    free_view = np.ones(view.n_params, bool)
    if free_camera == "rotation":
        free_view[3:] = False
    n = len(q0)
    free, unseen = np.ones((n, robot.nv), bool), np.zeros((n, robot.nv), bool)
    free[:10, 1] = False
    unseen[:5, 0] = unseen[-5:, 2] = True
    prior = _jerk_prior(unseen, 50.0, 10.0, 5.0) if smooth == "jerk" else _motion_prior(unseen, 50.0, 10.0)
    q0 = robot.clip(q0)  # a start inside the limits, as every fit's: a held joint stays where it is
    assert _prior_band(prior, n, robot.nv) is not None  # the prior as the compiled solver takes it
    out = []
    for use_compiled in (True, False):
        robot.__dict__.pop("_compiled", None)
        if not use_compiled:
            robot._compiled = None
        assert (compiled.CompiledModel.of(robot) is not None) == use_compiled
        args = (robot, q0, target, np.ones(target.shape[:2]), view, free if smooth else np.ones_like(free),
                free_view, 40, 1e-10, delta)
        out.append(_smooth_lm(*args, prior) if smooth else _sequence_lm(*args))
        if smooth:  # the first two steps alone: the same to rounding (the 40 steps end in one minimum
            # even with a step a little off)
            out.append(_smooth_lm(*args[:7], 2, *args[8:], prior))
    if smooth:
        np.testing.assert_allclose(robot.angles(out[1][0]), robot.angles(out[3][0]), rtol=0, atol=1e-9)
        out = out[::2]
    a, b = out
    if smooth:
        np.testing.assert_array_equal(robot.angles(a[0])[:10, 1], robot.angles(q0)[:10, 1])
        ang_a, ang_b = robot.angles(a[0]).ravel(), robot.angles(b[0]).ravel()
        cost_a, cost_b = (a[2] ** 2).sum() + ang_a @ (prior @ ang_a), (b[2] ** 2).sum() + ang_b @ (prior @ ang_b)
    else:
        cost_a, cost_b = (a[2] ** 2).sum(), (b[2] ** 2).sum()
    assert abs(cost_a - cost_b) <= 1e-6 * cost_b + 1e-20
    assert a[5] == b[5] and a[4].all() == b[4].all()
    va, vb = a[1], b[1]
    # (a run stopped at 40 steps in a flat valley: rounding moves its camera by up to a few millionths)
    np.testing.assert_allclose(va.R, vb.R, atol=1e-4)
    if kind == "pinhole":
        np.testing.assert_allclose([va.f, *va.c], [vb.f, *vb.c], rtol=1e-5)
        assert (va.f != view.f) == (free_camera != "all")
        assert (va.c != view.c).any() == (free_camera == "centre")
    else:
        np.testing.assert_allclose(np.r_[va.S, va.T[0]], np.r_[vb.S, vb.T[0]], rtol=1e-5, atol=1e-6)
        if free_camera == "rotation":
            np.testing.assert_array_equal(np.r_[va.S, va.T[0]], np.r_[view.S, view.T[0]])
    if smooth:  # the prior holds each joint to a smooth path through random poses: a descent, not a fit
        r0, ang0 = np.linalg.norm(view.apply(robot.positions(q0))[0] - target, axis=-1), robot.angles(q0).ravel()
        assert cost_a < 0.5 * ((r0 ** 2).sum() + ang0 @ (prior @ ang0))
    else:  # a fit, not noise: the residuals are those of 1 px noise (or exact 3D points)
        assert np.median(a[2]) < (1e-6 if kind == "3d" else 3.0)


def test_branch_steps_are_the_numpy_step_costs():
    # the branch path's step costs (candidates._branch_path): the same numbers as its numpy formula,
    # turning joints wrapped (steps of whole turns cost nothing), sliding ones not
    rng = np.random.default_rng(4)
    turning = np.array([True, True, False, True])
    qs = rng.normal(scale=3.0, size=(5, 40, 4))
    qs[0] = qs[0, 0]  # solution 0 standing still, solution 1 the same turned a whole turn: no step between them
    qs[1] = qs[0] + 2 * np.pi * turning * (np.arange(4) == 0)
    out = np.empty((5, 5, 39))
    compiled.branch_steps(qs, turning, 1, 0.15, 0.1, out)
    d = qs[None, :, 1:] - qs[:, None, :-1]
    jump = np.linalg.norm(np.where(turning, (d + np.pi) % (2 * np.pi) - np.pi, d), axis=-1)
    np.testing.assert_array_equal(out, (np.maximum(jump - 0.15, 0.0) / 0.1) ** 2)
    assert (out[0, 1] == 0.0).all() and out.max() > 100.0


def test_tasks_come_back_in_order_and_run_on_threads_only_where_the_kinematics_are_compiled(monkeypatch):
    import threading

    robot = _robot("ur10")
    monkeypatch.setenv("CHAINSPACE_THREADS", "2")
    started = []
    out = compiled.map_tasks(robot, lambda x: (x * x, threading.current_thread().name), range(6), started.append)
    assert [o[0] for o in out] == [x * x for x in range(6)] and started == list(range(6))
    assert all(name.startswith("chainspace-fit") for _, name in out)
    monkeypatch.setenv("CHAINSPACE_THREADS", "1")
    here = threading.current_thread().name
    assert [o[1] for o in compiled.map_tasks(robot, lambda x: (x, threading.current_thread().name), range(3))] == \
        [here] * 3
    monkeypatch.setenv("CHAINSPACE_THREADS", "2")
    robot._compiled = None  # kinematics looped over Pinocchio's one data: never on two threads
    assert [o[1] for o in compiled.map_tasks(robot, lambda x: (x, threading.current_thread().name), range(3))] == \
        [here] * 3


@pytest.mark.parametrize("camera", ["static", "pinhole"])
def test_a_robot_fit_on_two_threads_gives_the_numbers_of_one(monkeypatch, camera):
    # the fits tried from several starts run two at a time (compiled.map_tasks): each gives its own
    # numbers, and the choices among them are made in the order of the starts as on one thread
    import warnings

    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.synthetic.robot import synthesize

    chain = robot_chain("milling arm")
    trial = synthesize(chain, n_frames=30, noise_px=1.0, seed=3, **({"camera": "static"} if camera == "static" else {}))
    rec = reconstruct(trial.tracks, chain, seed=3)
    fits = []
    monkeypatch.setattr(compiled, "_task_pools", {})  # the pools this test's fits make
    for n in ("1", "2"):
        monkeypatch.setenv("CHAINSPACE_THREADS", n)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fits.append(fit_joint_angles(rec, camera="static", intrinsics=trial.intrinsics))
    assert any(key[1] == 2 for key in compiled._task_pools)  # the second fit did run on two threads
    a, b = fits
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.q_std, b.q_std)
    assert a.message == b.message and a.n_iter == b.n_iter and len(a.alternatives) == len(b.alternatives)


def test_tasks_mapped_inside_a_task_run_on_its_thread(monkeypatch):
    # a task that maps tasks itself must not wait on the pool it runs in (two such tasks would wait for ever)
    import threading

    robot = _robot("ur10")
    monkeypatch.setenv("CHAINSPACE_THREADS", "2")

    def outer(x):
        mine = threading.current_thread().name
        return [name == mine for name in compiled.map_tasks(robot, lambda y: threading.current_thread().name, range(3))]

    assert compiled.map_tasks(robot, outer, range(4)) == [[True] * 3] * 4
