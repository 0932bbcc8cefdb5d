"""The weak-perspective fit on the 2D tracks: step 2 of :func:`chainspace.robot.fit.fit_joint_angles`.

From the 3D fit's candidates (the reconstruction and its mirror image), :class:`WeakRefinement` fits
the joint angles and one weak-perspective camera to the tracks, then searches the motions that fit
them as well: every frame's branch chosen for the whole sequence, the two reflections that keep every
track (the depth mirror, and the mirror of a robot built mirror-symmetric), their mirrors far in joint
space, and the camera's freedom about a base whose tracked points lie on a line. :meth:`choose` then
picks among the fits with the motion prior, and :meth:`assess` says how sure the winner is
(:func:`chainspace.robot.uncertainty.assess_fit`).

A fit here is a dict: ``out`` (q, view, residual lengths, positions, converged, iterations) of the
solver, ``c`` the candidate it came from, ``cost``/``sse``/``n_obs`` on the tracks, ``gauge``/``g2``,
``free``/``free_prior`` (the directions it may move, without and with the motion prior), ``delta``
(the Huber threshold, px), ``down`` (how far its camera looks down on the base plane) and ``fixes``
(the branch search's rounds).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from ..progress import stage, stage_steps
from .candidates import (SYMMETRY_MIRROR, TIE_VARIANCES, _base_keeping_mirror, _far_poses, _mirror_targets,
                         _mirrored_motion, _nearest_rest_branch, _same_motion, _static_line_starts,
                         _viterbi_reanchored)
from .compiled import imap_tasks, map_tasks
from .kinematics import RobotKinematics, _rest_distance, _roughness
from .observability import _gauge_directions, _hold, _hold_with_prior, _unseen
from .selection import _most_probable, _prefer_rest, under_jerk_prior, view_side_valid
from .solver import _huber, _noise_sigma, _rms_per_frame, _robust_scale, _sequence_lm, acceleration_prior, \
    jerk_prior
from .starts import _fit_3d, _initial_camera, _sequential_ik
from .uncertainty import assess_fit
from .views import _affine_camera, _align, _camera_view, _looks_down

__all__ = ["WeakRefinement", "REFLECTION_ROUNDS"]

# rounds of reflecting the best motion while a reflection wins: two sufficed for arms; a quadruped's
# refits of its mirror went deeper for three
REFLECTION_ROUNDS = 4


class WeakRefinement:
    """One weak-perspective fit of ``robot`` to ``tracks`` (F, J, 2) px with weights ``w2`` (F, J), started
    from the 3D fit of the reconstruction (weights ``w3``): what it needs (the joints held ``blind``,
    ``free_blind``, the 3D fit's ``gauge0`` and ``free_sim``, the points ``unseen3`` in 3D), the solver's
    settings and ``view_from`` (the side of the base plane the camera is said to stand on).
    ``for_starts``: this fit only gives a perspective fit its starts; ``starts_only``: and is not
    reported or assessed (the intrinsics known), so the choices that serve a reported weak fit are cut
    short. ``timings`` (s) and ``n_iter`` (solver iterations) are added to as it runs."""

    def __init__(self, robot: RobotKinematics, tracks: np.ndarray, w2: np.ndarray, w3: np.ndarray,
                 blind: np.ndarray, free_blind: np.ndarray, gauge0: np.ndarray, free_sim: np.ndarray,
                 unseen3: np.ndarray, *, per_frame: bool, transform: str, max_iter: int, tol: float,
                 loss_scale_px: float | None, view_from: str | None, for_starts: bool, starts_only: bool,
                 timings: dict[str, float]):
        self.robot, self.tracks, self.w2, self.w3 = robot, tracks, w2, w3
        self.blind, self.free_blind, self.gauge0 = blind, free_blind, gauge0
        self.free_sim, self.unseen3 = free_sim, unseen3
        self.per_frame, self.transform, self.max_iter, self.tol = per_frame, transform, max_iter, tol
        self.loss_scale_px, self.view_from, self.starts_only = loss_scale_px, view_from, starts_only
        self.for_starts = for_starts
        self.timings = timings
        timings["branch_search"] = 0.0
        self.n_iter = 0
        # image-size tolerance for exact data: a thousandth of the tracks' extent (0.8 px at 800 px)
        self.px_floor = 1e-3 * float(max(np.ptp(tracks[..., 0][w2 > 0]), np.ptp(tracks[..., 1][w2 > 0])))
        self.unseen2 = _unseen(robot, w2)
        self.side_ok, self.side_why = view_side_valid(robot)  # legs hanging below their base: the side decides nothing
        self.base_mirror = _base_keeping_mirror(robot, (w2 > 0).any(0))
        # where the side decides nothing, the mirror image is searched far in joint space too, unless this fit
        # only gives the perspective fit its starts: perspective settles the mirror (and its starts for a
        # quadruped, Solo12 at seed 0 from below, led one leg into a wrong basin with the far mirrors among them)
        self.legs_mirror = not self.side_ok and not for_starts
        self._timed = threading.Lock()  # refine_2d runs on several threads (imap_tasks)
        self._far_found: dict[tuple[int, bool], tuple] = {}
        self._far_lock = threading.Lock()

    # ---- the refinement of one candidate, and of many in order
    def branches(self, *args):
        """:func:`~chainspace.robot.candidates._viterbi_reanchored`, timed: the sequence-wide branch search's share."""
        t = time.perf_counter()
        out = _viterbi_reanchored(*args)
        with self._timed:
            self.timings["branch_search"] += time.perf_counter() - t
        return out

    def robust_cost(self, rn: np.ndarray, delta: float | None) -> float:
        return float((self.w2 * _huber(rn, delta)[0]).sum())

    def on_one_of(self, q_fix: np.ndarray, fits) -> bool:
        """The rule that drops a candidate: its branch search put it on one of ``fits``."""
        return any(_same_motion(self.robot, q_fix, k["q"]) for k in fits)

    def seen_from_wrong_side(self, r: dict) -> bool:
        return self.side_ok and self.view_from is not None and (
            r["down"] < -0.02 if self.view_from == "above" else r["down"] > 0.02)

    def refine_2d(self, c: dict, known) -> dict:
        """The refined fit of candidate c (with its iterations, ``n_iter``), and ``fixes``: per round of the
        branch search, the motion it put c on and the iterations spent up to there (:meth:`refined` drops c
        at the first round on a fit refined before it); only ``fixes`` where a round put it on one of
        ``known`` (it is dropped then)."""
        robot, tracks, w2, per_frame, blind = self.robot, self.tracks, self.w2, self.per_frame, self.blind
        max_iter, tol, px_floor = self.max_iter, self.tol, self.px_floor
        n_iter, fixes = 0, []
        P0, _ = _affine_camera(c["pos"], tracks, w2, per_frame)
        pos, jac = robot.jacobians(c["q"])
        g2 = (_gauge_directions(pos, jac, w2, P0, per_frame) | c["gauge"]) & ~blind
        q, free, free_prior = _hold_with_prior(robot, c["q"], blind, g2 if per_frame else c["gauge"], per_frame,
                                               self.unseen2)
        view = c["camera0"] if "camera0" in c else _camera_view(c["pos"], tracks, w2, per_frame)
        # per-frame IK on the tracks with this camera (robust far from the solution), then all together
        if not c.get("whole_path"):  # a start from its first frame: rough elsewhere
            q = _sequential_ik(robot, tracks, w2, view, free, q[0], c["gauge"])
        for _ in range(4):  # alternate the closed-form camera(s) with per-frame IK
            view = _camera_view(robot.positions(q), tracks, w2, per_frame)
            q, _, _, _, _, it = _sequence_lm(robot, q, tracks, w2, view, free, np.zeros(6, bool), 10, 1e-8, None)
            n_iter += it
        pos = robot.positions(q)
        rn0 = np.linalg.norm(view.apply(pos)[0] - np.nan_to_num(tracks), axis=-1)
        loss = self.loss_scale_px
        delta = _robust_scale(rn0, w2, px_floor) if loss is None else (float(loss) if loss > 0 else None)
        out = _sequence_lm(robot, q, tracks, w2, view, free, np.ones(6, bool), max_iter, tol, delta)
        # then the branch of every frame, chosen for the whole sequence: twice, once for starts only
        # (with no pass there the Kinova from above, full ranges, seed 31, started the perspective fit
        # from a near mirror image and ended there, joint 2 off by 47 degrees, reported observable)
        for _ in range(1 if self.starts_only else 2):
            sig = max(_noise_sigma(out[2], w2), px_floor)
            q_fix, view_fix = self.branches(robot, out[0], tracks, w2, out[1], free, sig, c["gauge"], per_frame,
                                            blind, self.unseen2)
            fixes.append((q_fix, n_iter + out[-1]))
            if self.on_one_of(q_fix, known):
                return dict(fixes=fixes)
            if _same_motion(robot, q_fix, out[0]):
                break
            new = _sequence_lm(robot, q_fix, tracks, w2, view_fix, free, np.ones(6, bool), max_iter, tol, delta)
            if not self._takes_over(new, out, delta, c["gauge"]):
                break
            out = new
        # free where unseen too: a branch held there could not turn with the rest of its path
        q_rest_branch = out[0] if self.starts_only else _nearest_rest_branch(robot, out[0], free_prior)
        if q_rest_branch is not out[0]:
            out = _sequence_lm(robot, q_rest_branch, tracks, w2, out[1], free, np.ones(6, bool), max_iter, tol, delta)
        return dict(cost=float(np.sqrt((w2 * out[2] ** 2).sum() / w2.sum())), sse=float((w2 * out[2] ** 2).sum()),
                    n_obs=2 * int((w2 > 0).sum()), out=out, c=c, g2=g2,
                    q=out[0], gauge=g2, down=_looks_down(out[1]), free=free, free_prior=free_prior, delta=delta,
                    fixes=fixes, n_iter=n_iter + out[-1])

    def _takes_over(self, new: tuple, out: tuple, delta: float | None, gauge: np.ndarray) -> bool:
        """Whether the branch search's refit ``new`` replaces ``out``: only a better fit of the tracks, or an
        equal fit by a smoother path or nearer the rest pose."""
        robot, w2 = self.robot, self.w2
        worst_old = np.nanmax(_rms_per_frame(out[2], w2))
        better = self.robust_cost(new[2], delta) <= 0.99 * self.robust_cost(out[2], delta) and \
            np.nanmax(_rms_per_frame(new[2], w2)) <= 1.1 * worst_old + self.px_floor
        # a tie of the tracks (a wrist whose tracked points lie in one plane, mirrored in depth):
        # the continuous path wins, and of two alike continuous ones the one nearer the rest pose
        tie = self.robust_cost(new[2], delta) <= 1.05 * self.robust_cost(out[2], delta)
        rough_new, rough_old = _roughness(robot, new[0]), _roughness(robot, out[0])
        smoother = rough_new < 0.5 * rough_old and rough_old - rough_new > 1.0  # a jump gone
        nearer = rough_new <= 1.5 * rough_old + 1.0 and \
            _rest_distance(robot, new[0], new[0][:1], gauge).mean() < \
            _rest_distance(robot, out[0], out[0][:1], gauge).mean() - 0.1
        return better or tie and (smoother or nearer)

    def refined(self, starts, known=(), step=None) -> list[dict]:
        """The fits of those starts that are new motions, in order: a start is dropped where a round of its
        branch search puts it on a fit in ``known`` or refined before it (both mirror starts of an arm whose
        mirror image is no pose of it end on one motion, which would be refined, searched and smoothed
        twice). On several threads a start is refined while those before it may still run, so it stops
        early only on the ones it sees done (``seen``) and is dropped here as if refined after them all: the
        same fits and counts as on one thread."""
        new: list[dict] = []
        seen = list(known)
        for r in imap_tasks(self.robot, lambda c: self.refine_2d(c, seen), starts, step):
            dropped_at = next((it for q_fix, it in r["fixes"] if self.on_one_of(q_fix, seen)), None)
            self.n_iter += r["n_iter"] if dropped_at is None else dropped_at
            if dropped_at is None:
                new.append(r)
                seen.append(r)
        return new

    # ---- which fits tie, and their order
    def tracks_tie(self, a: dict, b: dict) -> bool:
        """Refined fits: b is as good as a unless its squared residuals exceed a's by more than 25 noise
        variances (a likelihood ratio test, noise estimated from a's residuals)."""
        var = max(a["sse"] / max(a["n_obs"], 1), (0.05 * self.px_floor) ** 2)
        return b["sse"] - a["sse"] <= TIE_VARIANCES * var

    def order(self, rs: list[dict]) -> tuple[list[dict], bool]:
        """Among the fits the tracks cannot tell apart: seen from the right side first, then the one nearer
        the rest pose; and whether more than one tie."""
        best_fit = min(rs, key=lambda r: r["sse"])
        n_tied = sum(self.tracks_tie(best_fit, r) for r in rs)
        rs = _prefer_rest(self.robot, rs, "cost", self.blind, tie=self.tracks_tie)
        rs[:n_tied] = sorted(rs[:n_tied], key=self.seen_from_wrong_side)
        return rs, n_tied > 1

    # ---- reflections
    def far_mirrors(self, r: dict, up_to_links: bool) -> list[np.ndarray]:
        """r's points mirrored by the reflection that keeps the base points in place (an arm's vertical
        plane, a quadruped's trunk plane: candidates._base_keeping_mirror), as poses wherever they lie in
        joint space: whole, or (up_to_links) with each link and all beyond it mirrored back in depth under
        r's camera (the same image: the mirror of the arm up to that link). Searched once per motion (r
        kept with its result, so that its id is not reused)."""
        key = (id(r), up_to_links)
        with self._far_lock:  # (a round's two reflections ask for the same searches at once: made once)
            if key not in self._far_found:
                X = r["out"][3]
                targets = _mirror_targets(self.robot, X, r["out"][1]) if up_to_links else [X]
                self._far_found[key] = (r, _far_poses(self.robot, r["out"][0], [self.base_mirror(m) for m in targets],
                                                      self.free_blind) if self.base_mirror is not None else [])
            return self._far_found[key][1]

    def reflection(self, r: dict, M: np.ndarray, up_to_links: bool = True) -> tuple[list[dict], int]:
        """r's motion reflected by M (3 x 3, base frame), fitted in 3D from the refined motion (a far better
        start than the reconstruction): candidates to refine on the tracks, the first its fit (the mirrors
        up to each link after it only with ``up_to_links``), and the iterations spent (returned, not
        counted here: a round's two reflections are made on two threads)."""
        robot, w3 = self.robot, self.w3
        X_alt = np.einsum("ij,fkj->fki", M, r["out"][3])
        q_a, view_a, it_a = _fit_3d(robot, X_alt, w3, self.free_blind, self.transform, self.max_iter, self.tol,
                                    self.gauge0)
        spent = [it_a]

        def fitted(q_s):
            q_s, free_a = _hold(robot, q_s, self.blind, r["c"]["gauge"], False, self.unseen3)
            view_a = _align(robot.positions(q_s), X_alt, w3, self.transform)
            out = _sequence_lm(robot, q_s, X_alt, w3, view_a, free_a, self.free_sim, 20, self.tol, None)
            spent.append(out[5])
            return out

        def candidate(q_s, pos, conv, **kw):
            return dict(sign=-r["c"]["sign"], q=q_s, pos=pos, gauge=r["c"]["gauge"], conv=conv, **kw)

        best, partial, whole = fitted(q_a), [], False
        # (the starts of a perspective fit with K known search them for every arm's motion, the side
        # it was told being no rule there: the Kinova from below, full ranges, pinhole, seed 48, told
        # "above" by default, ended with joints 2 and 3 19 and 112 degrees off, reported observable)
        far_side = self.seen_from_wrong_side(r) or self.legs_mirror or (self.starts_only and self.side_ok)
        if (w3 * best[2]).max() > 1e-3 * robot.reach() and far_side:
            # X_alt is a robot's motion reflected: where the 3D fit did not reach it and r is seen
            # from the wrong side (the mirrors of one seen from the right side lose to it), or the
            # side decides nothing (legs_mirror), the poses that take r's points mirrored (every reflection of
            # the points is the base-keeping mirror turned: M times that mirror is a rotation). A
            # quadruped (Solo12, full ranges, weak camera) ended on the exact mirror of its truth, every
            # joint 12-154 degrees off and none flagged, its legs' mirror half a turn away. A UR10 seen
            # from below had the exact mirror of the winner as its truth, five joints 40-137 degrees
            # away, and was reported seen from above against the side it was told; a Kinova arm the
            # mirror up to its wrist (the hand's points at the winner's depths), three joints 11-149
            # degrees away.
            partial = self.far_mirrors(r, True) if up_to_links else []
            for q_s in self.far_mirrors(r, False):
                far = fitted(q_s)
                if (w3 * far[2] ** 2).sum() < (w3 * best[2] ** 2).sum():
                    best, whole = far, self.legs_mirror
        fits = [(best, whole)]
        exact = _mirrored_motion(robot, r["out"][0], self.base_mirror) if self.base_mirror is not None else None
        if exact is not None:
            # a mirror-symmetric robot's mirror image, joint by joint, first where it fits the mirrored
            # points at least as well: the 3D fit reaches them frame by frame, on any branch of the wrist
            # in each frame, and the motion prior's refit of such a path can end in another basin. The
            # milling arm from below (full ranges, seed 33): the winner seen from above, its reflected
            # start's wrist jumping between branches, smoothed 100 times higher; the first joint reported
            # 50 degrees off, unflagged. The 3D fit's own path stays a candidate: from a poor winner it
            # can lead to a better basin than the exact mirror of that winner (the Z1 from below, seed 26)
            mirrored = fitted(exact)
            if not _same_motion(robot, mirrored[0], best[0]):
                first = (w3 * mirrored[2] ** 2).sum() <= (w3 * best[2] ** 2).sum()
                fits.insert(0 if first else 1, (mirrored, self.legs_mirror))
        # the partial mirrors are whole paths through every frame: refined from all of them, since
        # the per-frame IK from their first frame drifted onto the hand's other branches (the Kinova);
        # so is a quadruped's whole mirror (per-frame IK drifted onto its legs' other branches; an
        # arm's whole mirror refined as a whole path ended in a wrong basin of the xArm7's wrist)
        return [candidate(f[0], f[3], f[4], whole_path=whole_f) for f, whole_f in fits] + \
            [candidate(q_s, robot.positions(q_s), True, whole_path=True) for q_s in partial], sum(spent)

    def depth_mirror(self, r: dict) -> np.ndarray:
        R0 = r["out"][1].R[0] if not self.per_frame else r["out"][1].R.mean(0)
        return R0.T @ np.diag([1.0, 1.0, -1.0]) @ R0

    def rebranch(self, r: dict, out: tuple):
        sig = max(_noise_sigma(out[2], self.w2), self.px_floor)
        return self.branches(self.robot, out[0], self.tracks, self.w2, out[1], r["free"], sig, r["c"]["gauge"],
                             self.per_frame, self.blind, self.unseen2)

    def reflected_start(self, r: dict) -> dict:
        """r's depth mirror image, a start for the smoothed fit (held as the refinement holds)."""
        made, spent = self.reflection(r, self.depth_mirror(r), up_to_links=False)
        self.n_iter += spent
        c = made[0]
        q, _, free_prior = _hold_with_prior(self.robot, c["q"], self.blind, c["gauge"], False, self.unseen2)
        return dict(r, c=c, q=q, free_prior=free_prior,
                    view=_camera_view(self.robot.positions(q), self.tracks, self.w2, False))

    # ---- the search as a whole
    def search(self, candidates: list[dict]) -> tuple[list[dict], bool]:
        """The refined fits from the 3D fit's ``candidates`` and from every search, best first (:meth:`order`),
        and whether the best ties with another."""
        robot, tracks, w2 = self.robot, self.tracks, self.w2
        # both mirror images: a poor reconstruction may favour the wrong one in 3D
        results = self.refined(candidates, step=stage_steps("robot fit: refining on the tracks, candidate",
                                                            len(candidates)))
        if not self.per_frame and self.transform == "similarity" and \
                min(r["cost"] for r in results) > 3 * self.px_floor:
            # the tracks are fitted poorly from the reconstruction's start: also a camera found from the
            # tracks alone (costly, so only then)
            v2, q2 = _initial_camera(robot, tracks, w2, _hold(robot, candidates[0]["q"], self.blind,
                                                              candidates[0]["gauge"], False)[1])
            alt = self.refined([dict(candidates[0], q=q2, pos=robot.positions(q2), camera0=v2)], results)
            if alt and alt[0]["cost"] * 1.5 < min(r["cost"] for r in results):  # clearly better, not a tie
                results += alt
        results, tied = self.order(results)
        if self.transform != "similarity":
            return results, tied
        # Two reflections keep every track: the depth mirror (weak perspective), and for a robot built
        # mirror-symmetric (its tracked points in one vertical plane at rest) the mirror about that plane,
        # seen through the mirrored camera. The best motion is tried under both; when a reflection wins (a
        # better fit found from the reflected start), it is reflected in turn, since its own mirror image
        # may be the one seen from the right side, or tie with it (a quadruped's legs: each round's refit
        # went deeper, hundreds of noise variances, for three rounds).
        reflected: list[dict] = []
        while len(reflected) < REFLECTION_ROUNDS and not any(results[0] is r for r in reflected):
            r0 = results[0]
            reflected.append(r0)
            stage(f"robot fit: refining the best fit's two reflections on the tracks (round %d of at most "
                  f"{REFLECTION_ROUNDS})", len(reflected))
            made = map_tasks(robot, lambda M: self.reflection(r0, M), (self.depth_mirror(r0), SYMMETRY_MIRROR))
            self.n_iter += sum(spent for _, spent in made)
            alts = self.refined([c for cs, _ in made for c in cs], results)
            results, tied = self.order(results + alts)
        if not self.per_frame:
            t_s = time.perf_counter()
            results, tied = self._turned_about_base_line(results, tied)
            self.timings["static_line"] = time.perf_counter() - t_s
        if not self.per_frame and not self.for_starts:
            results, tied = self._near_twins_of_fits(results, tied)
        return results, tied

    def _near_twins_of_fits(self, results: list[dict], tied: bool) -> tuple[list[dict], bool]:
        """The refined fits' near twins over the shoulder (:func:`chainspace.robot.uncertainty._near_twins`),
        each under a camera fitted to its points, refined as the rest (a perspective fit refits its own, so
        not where this fit only gives one its starts). The Kinova from above and from below through a weak
        camera (full ranges, seed 67): joints 2 and 3 150 and 132 degrees off, reported observable, and
        nothing tied; the near twin of the runner-up (the winner's depth mirror, 6,845 px^2) fits exactly as
        the winner does (561.8 px^2) with joints 2 and 3 within 0.4 degrees: a tie no candidate showed."""
        from .uncertainty import _near_twins

        twins = [(r, q_n, self.robot.positions(q_n)) for r in results
                 for q_n in _near_twins(self.robot, r["out"][0], r["free"])]
        starts = [dict(r["c"], q=q_n, pos=pos, camera0=_camera_view(pos, self.tracks, self.w2, False))
                  for r, q_n, pos in twins]
        # (one seen from the side the user ruled out is set aside: refined after the reflections, it would not
        # be reflected, and the Kinova from below, seed 81, ended on such a twin, joints 2-3 155 degrees off)
        alts = [r for r in self.refined(starts, results) if not self.seen_from_wrong_side(r)]
        return self.order(results + alts) if alts else (results, tied)

    def _turned_about_base_line(self, results: list[dict], tied: bool) -> tuple[list[dict], bool]:
        """The camera's freedom about the base's line of tracked points: the best motion turned about it, or
        mirrored in depth (whole, or up to one link) and turned back onto the base points
        (candidates._static_line_starts); the basins that fit as well or better, refined as the rest. When
        one of them wins it is turned in turn, as a winning reflection is reflected: the TALOS arm from
        above (weak camera, full ranges, seed 45) went from a poor lead to the true motion turned half a
        turn about the line (arm_left_2 57, arm_left_3 172 degrees off, reported observable), and only that
        winner's own turn leads back to the truth."""
        turned_from: list[dict] = []
        while len(turned_from) < REFLECTION_ROUNDS and not any(results[0] is r for r in turned_from):
            r0 = results[0]
            turned_from.append(r0)
            lead = dict(q=r0["out"][0], view=r0["out"][1], pos=r0["out"][3], gauge=r0["gauge"],
                        free=r0["free"], delta=r0["delta"], sse=r0["sse"], var=r0["sse"] / max(r0["n_obs"], 1))
            turned = self.refined((dict(r0["c"], q=q_s, pos=self.robot.positions(q_s), camera0=v_s)
                                   for q_s, v_s in _static_line_starts(self.robot, lead, self.tracks, self.w2,
                                                                       TIE_VARIANCES)), results)
            if turned:
                results, tied = self.order(results + turned)
        return results, tied

    # ---- the choice with the motion prior, and how sure it is
    def choose(self, results: list[dict], tied: bool, accel_std: float | None, fps: float,
               speed_decay_s: float | None, jerk_std: float | None = None) -> tuple[dict, list[dict], bool, object,
                                                                                 float, list]:
        """The most probable fit under the motion prior (joint accelerations ~ N(0, accel_std^2) rad/s^2
        against the measured pixel noise), where there is one (a static camera, three frames or more, some
        noise), each scored fit then finished under the jerk prior (``jerk_std`` rad/s^3;
        :func:`chainspace.robot.selection.under_jerk_prior`; None: not): (winner, fits best first, whether
        it ties, the prior the fits end under or None, the noise sigma px, the scored (objective, fit) pairs)."""
        r = results[0]
        sigma = _noise_sigma(r["out"][2], self.w2)
        F = len(self.tracks)
        if accel_std is None or F < 3 or self.per_frame or sigma <= 1e-6:
            return r, results, tied, None, sigma, []
        prior = acceleration_prior(self.unseen2, sigma, accel_std, fps, speed_decay_s)
        stage("robot fit: choosing among %d fits with the motion prior", len(results))
        scored: list = []
        r, tied, it = _most_probable(self.robot, results, self.tracks, self.w2, prior, max(sigma, self.px_floor),
                                     self.max_iter, self.tol, self.seen_from_wrong_side, self.reflected_start,
                                     self.rebranch, scored, reflect_always=self.legs_mirror)
        self.n_iter += it
        if jerk_std is not None and F > 3:  # the answer and its alternatives finished under the jerk prior
            prior = jerk_prior(self.unseen2, sigma, jerk_std, fps, speed_decay_s)
            fits = [(x["out"][0], x["out"][1], x["free_prior"], x["delta"]) for _, x in scored]
            for i, (objective, out) in enumerate(under_jerk_prior(self.robot, fits, self.tracks, self.w2, prior,
                                                                  self.max_iter, self.tol)):
                x = scored[i][1]
                x.update(out=out, q=out[0], down=_looks_down(out[1]))
                scored[i] = (objective, x)
                self.n_iter += out[5]
        results = [r] + [x for _, x in sorted(scored, key=lambda sx: sx[0]) if x is not r]
        return r, results, tied, prior, sigma, scored

    def assess(self, r: dict, results: list[dict], prior, sigma: float, scored: list, gauge: np.ndarray,
               search_ties: bool, camera_assumed: bool) -> dict:
        """How sure the winner ``r`` is (:func:`chainspace.robot.uncertainty.assess_fit`): against the
        smoothed fits' scores where the prior chose, else the refined fits compared on the tracks alone
        (as :meth:`tracks_tie` does)."""
        if prior is not None:
            tie_var = max(sigma, self.px_floor) ** 2
        else:
            tie_var = max(r["sse"] / max(r["n_obs"], 1), (0.05 * self.px_floor) ** 2)
            scored = [(x["sse"], x) for x in results]
        stage("robot fit: the joint angles' standard deviations and alternatives")
        return assess_fit(self.robot, r, scored, tie_var, self.tracks, self.w2, prior, self.blind, gauge,
                          self.seen_from_wrong_side, self.side_why if self.view_from is not None else "",
                          search=search_ties, camera_assumed=camera_assumed)
