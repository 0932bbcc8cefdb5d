"""The choice among candidate motions that fit the tracks alike (see the rules in
:mod:`chainspace.robot.fit`): nearest the rest pose, the most probable under the motion prior.
"""

from __future__ import annotations

from collections.abc import Callable
import numpy as np

from ..progress import stage_steps
from .kinematics import RobotKinematics, _roughness
from .compiled import imap_tasks, map_tasks
from .views import _View, _looks_down
from .solver import _smooth_lm, _smoothed_objective
from .candidates import TIE_VARIANCES, _LONG_GAP, _across_long_gaps, _same_motion, _turned_views
from .starts import _whole_turn_joint


def view_side_valid(robot: RobotKinematics) -> tuple[bool, str]:
    """Whether the camera-side rule (``view_from``) may settle a mirror tie for this robot, and why not.

    The rule assumes an arm standing on a fixed base, filmed by a camera on its side of the base plane
    (above the floor). It is valid when the tracked points at rest lie above the base plane on
    average (z > 0 in the base frame): an arm on a floor, or on a ceiling with its base frame turned
    over. Legs hanging below their trunk (a quadruped fitted as a fixed-base tree, a humanoid's arm
    from its shoulder) break it: the mirror images are then left to a guess and reported as such."""
    pos = robot.positions(robot.q_rest)[0]
    above = float(np.mean(pos[:, 2]))
    if above > 0.05 * robot.reach():
        return True, ""
    return False, (f"the tracked points hang below the base plane at rest (mean height {1000 * above:.0f} mm): "
                   "legs or a hanging limb, where the camera-side rule (view_from) does not apply")


def _prefer_rest(robot: RobotKinematics, cands: list[dict], key: str, blind: np.ndarray,
                 floor: float = 0.0, tie=None) -> list[dict]:
    """Candidates sorted by their error ``key``; among those the data cannot tell apart (error within
    1.5 times the best plus ``floor``, as a mirror image often fits as well as the truth; or
    ``tie(best, c)``), the nearest the rest pose (mean absolute joint offset over the fitted,
    observable joints) comes first."""
    cands = sorted(cands, key=lambda c: c[key])
    tie = tie or (lambda b, c: c[key] <= 1.5 * b[key] + floor + 1e-12)
    tied = [c for c in cands if tie(cands[0], c)]

    def distance(c):
        seen = ~(blind | c["gauge"])
        d = robot.angles(c["q"]) - robot.angles(robot.q_rest)  # per degree of freedom (nv)
        d = robot.wrap_angles(d)[:, seen]
        return float(np.abs(d).mean()) if d.size else 0.0

    tied.sort(key=distance)
    tied_ids = {id(c) for c in tied}  # identity: `in` would compare the dicts' arrays
    return tied + [c for c in cands if id(c) not in tied_ids]


def _most_probable(robot: RobotKinematics, results: list[dict], tracks: np.ndarray, w: np.ndarray, prior,
                   sigma: float, max_iter: int, tol: float, wrong_side: Callable[[dict], bool],
                   reflected: Callable[[dict], dict],
                   rebranch: Callable[[dict, tuple], tuple[np.ndarray, _View]],
                   scored_out: list | None = None, reflect_always: bool = False) -> tuple[dict, bool, int]:
    """The fit of the most probable motion under the smoothness prior, among ``results`` (refined fits,
    preferred first): each distinct fit that the tracks alone nearly tie is smoothed (:func:`_smooth_lm`)
    and scored by the smoothed objective, robust residuals plus the motion prior (``prior``, the sparse
    matrix of :func:`_motion_prior`), with one Huber threshold for all; a direction that no point seen
    in a frame moves is free there (``free_prior``: the prior interpolates it). When the lowest is seen
    from the wrong side (``wrong_side``), or always with ``reflect_always`` (legs, whose side decides
    nothing: the smoothed winner's mirror is reached where the unsmoothed fits' was not), its mirror
    image (``reflected``: a start with ``q``, ``view``, ``free_prior``) is smoothed and scored too. Each
    smoothed fit then gets the branch of every frame chosen again (``rebranch``, a Viterbi pass) and is
    smoothed again while that lowers its score. The best is smoothed again from views turned about
    its gauge joint and its first joint that turns every tracked point
    (:func:`~chainspace.robot.starts._whole_turn_joint`; :func:`_turned_views`). Of the fits within 25
    noise variances of the lowest score, the one that moves least (:func:`_roughness`) among those seen
    from the right side wins, else among all; it is returned with its smoothed ``out``.

    Why: a motion that fits the tracks a little better frame by frame (a wrong mirror image of a
    nearly symmetric robot, a branch that jumps) may do so only by moving less plausibly, and the
    prior is what says how plausible a motion is. The refinement frame by frame can also leave jumps
    in one mirror image and not in the other: the smooth one, reflected, gives that side a smooth
    start. The turns about a first joint that is no gauge: its turn differs from the camera's only at
    the base's tracked points off its axis, which may lie near it (the double pendulum's, 35 mm: through
    a weak camera, full ranges, seeds 54 and 55, joint1 157 and 138 degrees off, reported observable,
    where the truth's basin fits the tracks as well). Returns (fit, whether another distinct fit tied,
    iterations).
    """
    best_sse = min(r["sse"] for r in results)
    delta = results[0]["delta"]
    scored: list[tuple[float, dict]] = []
    n_iter = 0

    def smoothed(r, q, view):
        out = _smooth_lm(robot, robot.continuous(q), tracks, w, view, r["free_prior"], np.ones(6, bool), max_iter,
                         tol, delta, prior)
        return _smoothed_objective(prior, robot.angles(out[0]), out[2], w, delta), out

    def known(q):
        return any(_same_motion(robot, q, o["q"]) for _, o in scored)

    def scoring(r, q, view, new_start):
        """(first, objective, out, iterations): r smoothed from (q, view) (``first``: its out), then (when
        that is no motion scored already) smoothed again while a new branch choice lowers its objective;
        None where ``new_start`` and q is a motion scored already."""
        if new_start and known(q):
            return None
        objective, out = smoothed(r, q, view)
        first, n = out, out[5]
        if known(out[0]):
            # smoothed back onto a motion already scored, whose branches were searched then: the
            # search would find what it found before, and the motion keeps its place in the order
            return first, objective, out, n
        for _ in range(2):  # the smoothed motion may still jump branches that a local step cannot undo
            q_b, view_b = rebranch(r, out)
            if _same_motion(robot, q_b, out[0]):
                break
            objective_b, out_b = smoothed(r, q_b, view_b)
            n += out_b[5]
            if objective_b >= (1 - 1e-3) * objective:
                break
            objective, out = objective_b, out_b
        return first, objective, out, n

    def score_in_order(tries, new_starts=False, step=None):
        """Score each (r, q, view) of ``tries``: on several threads at once (each scoring sees the scores
        taken before it that are done: imap_tasks), taken here in order as if one after the other. With
        ``new_starts`` a start that is a motion scored before is not scored; a first smoothed fit that is
        one is dropped (the iterations after it not counted); a scored one whose final motion was scored
        before keeps that one's place in the order."""
        nonlocal n_iter
        tries = list(tries)
        for (r, q, _), done in zip(tries, imap_tasks(robot, lambda t: scoring(*t, new_starts), tries, step)):
            if done is None or new_starts and known(q):
                continue
            first, objective, out, n = done
            if known(first[0]):
                n_iter += first[5]
                continue
            n_iter += n
            if not known(out[0]):  # else a motion met before, which keeps its place in the order
                scored.append((objective, dict(r, out=out, q=out[0], down=_looks_down(out[1]))))

    # the fits near the best on the tracks (a poor fit of the tracks is not scored)
    near = [(r, r["out"][0], r["out"][1]) for r in results if r["sse"] <= 1.1 * best_sse + TIE_VARIANCES * sigma ** 2]
    score_in_order(near, True, stage_steps("robot fit: the motion prior, scoring fit", len(near)))  # a UR5's four: 14 s
    best, r = min(scored, key=lambda sr: sr[0])
    turning = r["gauge"].copy()  # the camera's azimuth about the first joint's axis is a guess either way
    k = _whole_turn_joint(robot, r["q"])
    if k is not None:
        turning[k] = True
    score_in_order([(r, r["q"], view_t) for view_t in _turned_views(robot, r["q"], r["out"][1], turning)])
    best, r = min(scored, key=lambda sr: sr[0])
    # a joint seen again after a long gap: the bridges to its other branches that score alike (the
    # acceleration prior charges nothing for a straight ramp), the one that moves least wins
    least = (_roughness(robot, r["q"]), best, r)
    gaps = _across_long_gaps(robot, r["q"], tracks, w, r["out"][1], r["free"], sigma, _LONG_GAP)
    for objective, out in map_tasks(robot, lambda q_b: smoothed(r, q_b, r["out"][1]), gaps):
        n_iter += out[5]
        moved = _roughness(robot, out[0])
        if objective <= best + TIE_VARIANCES * sigma ** 2 and moved < least[0]:
            least = (moved, objective, dict(r, out=out, q=out[0], down=_looks_down(out[1])))
    if least[2] is not r:
        scored = [sr for sr in scored if sr[1] is not r] + [least[1:]]
        r = least[2]
    if wrong_side(r) or reflect_always:
        start = reflected(r)
        score_in_order([(start, start["q"], start["view"])])
    lowest = min(sr[0] for sr in scored)
    tied = [r for sr, r in scored if sr - lowest <= TIE_VARIANCES * sigma ** 2]
    if scored_out is not None:
        scored_out.extend(scored)
    return min(tied, key=lambda r: (wrong_side(r), _roughness(robot, r["q"]))), len(tied) > 1, n_iter


def under_jerk_prior(robot: RobotKinematics, fits: list[tuple[np.ndarray, object, np.ndarray, float | None]],
                     tracks: np.ndarray, w: np.ndarray, jerk, max_iter: int, tol: float) -> list[tuple]:
    """Each fit (q (F, nq), view, free directions (F, nv), Huber threshold) smoothed again from where it is,
    camera too, under the jerk prior ``jerk`` (:func:`chainspace.robot.solver.jerk_prior`): [(objective,
    solver out)], the objectives (robust residuals plus the prior) comparable with one another.

    Why: the search for the motion and its alternatives runs under the acceleration prior, whose stiffness
    keeps the smoothed objective's basins apart (under the jerk prior, through a weak camera over full
    joint ranges, seeds 54-57, the Panda and the TALOS arm ended in wrong basins that the acceleration
    prior's search avoids); but it pulls a joint the tracks fix poorly towards rest: the UR3 from below
    (pinhole, seed 79), its wrist_1 accelerating at 4-6 rad/s^2 near the wrist singularity, came out 3.1
    degrees off, 1.8 RMS on average over 12 noise draws (z 2.4) where the jerk prior gives 0.5 (z 0.9).
    So the answer, its alternatives and their scores are the search's fits finished under the jerk prior."""
    def finish(fit):
        q, view, free, delta = fit
        out = _smooth_lm(robot, robot.continuous(q), tracks, w, view, free, np.ones(view.n_params, bool), max_iter,
                         tol, delta, jerk)
        return _smoothed_objective(jerk, robot.angles(out[0]), out[2], w, delta), out

    return map_tasks(robot, finish, fits)
