"""How well the tracks pin each joint down: per-frame, per-joint standard deviations of a fit.

The refinement minimises ``sum w |r|^2 + q' M q`` (robust residuals r in pixels with IRLS weights w,
the motion prior M of :func:`chainspace.robot.solver._motion_prior`). Read as a negative log
posterior with pixel noise sigma, its Gauss-Newton covariance at the solution is

    Cov = sigma^2 H^-1,   H = [[J_q' W J_q + M, J_q' W J_c], [J_c' W J_q, J_c' W J_c]]

with q the joint angles of every frame and c the static camera. Only the per-frame diagonal blocks of
the q part are needed. The camera is eliminated by a Schur complement, and the joint-angle block,
banded (the acceleration prior couples a frame to the two either side, the jerk prior to the three), is
block-tridiagonal in blocks of that many frames; the diagonal blocks of its inverse follow from one
forward and one backward recursion (``inv(L_k + R_k - A_k)``, L and R the Schur complements from either
end), so the cost is linear in the number of frames.

sigma is measured from the fit's own residuals: the robust (median) estimate of
:func:`chainspace.robot.solver._noise_sigma`, corrected for the degrees of freedom the fit used
(``n_obs / (n_obs - p_eff)``, ``p_eff = trace(H^-1 H_data)``; the residuals of a fit are smaller than
the noise by the share of it the fitted parameters absorbed).

What the fit does not know is reported as ``ambiguous`` joints (:func:`assess_fit`): where another
motion fits as well (the fit's candidates, the depth flips, the wrist's exact Euler twins
(:func:`_wrist_twins`) and, with ``search_ties``, the searches) and differs by more than
:data:`AMBIGUOUS_DEG`; where the fit misses a tracked point in most frames ("poor fit",
:func:`poor_fit_joints`), or a base point on average (:func:`base_offsets`: the camera is off): a wrong
basin nothing ties with is still not an answer; and where the joint's own standard deviation, twice over
(:data:`UNCERTAIN_SIGMAS`), plus its difference from an alternative that fits as well, is more than
:data:`AMBIGUOUS_DEG` ("uncertain", :func:`uncertain_joints`): the tracks do not pin it down to the
accuracy claimed; and every joint where the solver stopped before it converged ("not converged"). Each
flagged joint's reasons are returned one per joint (``reasons``, ``JointFit.joint_reasons``).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..metrics import procrustes_align
from .compiled import map_tasks
from .kinematics import RobotKinematics, _relative_difference
from .observability import _point_movers
from .solver import _huber, _noise_sigma, _normal_equations, prior_frames
from .views import similarity_align


def _block_tridiagonal_inverse_diagonal(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Diagonal blocks (n, b, b) of the inverse of the symmetric positive definite block-tridiagonal
    matrix with diagonal blocks A (n, b, b) and super-diagonal blocks B (n - 1, b, b)."""
    n = len(A)
    L, R = A.copy(), A.copy()
    for k in range(1, n):  # Schur complements from the first block on ...
        L[k] = A[k] - B[k - 1].T @ np.linalg.solve(L[k - 1], B[k - 1])
    for k in range(n - 2, -1, -1):  # ... and from the last one back
        R[k] = A[k] - B[k] @ np.linalg.solve(R[k + 1], B[k].T)
    return np.linalg.inv(L + R - A)


def _frame_blocks(H, F: int, nv: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """H (F nv, F nv) sparse, bandwidth m frames, as blocks of m frames each (the last padded with an
    identity where m does not divide F): diagonal (n, m nv, m nv) and super-diagonal (n - 1, m nv, m nv)."""
    import scipy.sparse as sp

    b = m * nv
    n = (F + m - 1) // m
    pad = n * b - F * nv
    Hp = sp.block_diag([H, sp.eye(pad)]).tocsr() if pad else H.tocsr()
    A = np.stack([Hp[k * b:(k + 1) * b, k * b:(k + 1) * b].toarray() for k in range(n)])
    B = np.stack([Hp[k * b:(k + 1) * b, (k + 1) * b:(k + 2) * b].toarray() for k in range(n - 1)]) if n > 1 \
        else np.zeros((0, b, b))
    return A, B


def joint_std(robot: RobotKinematics, q: np.ndarray, tracks: np.ndarray, w: np.ndarray, view, free: np.ndarray,
              delta: float | None, prior=None) -> tuple[np.ndarray, float]:
    """Standard deviations (F, nv) of the fitted joint angles q (F, nq) (radians; metres for prismatic
    joints) and the measured pixel noise sigma (px, per image coordinate).

    tracks (F, J, D) and weights w (F, J) as fitted; ``view`` the fitted camera(s) (one static view, or
    one per frame); free (F, nv) the directions the fit moved (others are held: their entries are NaN,
    and the caller sets those fixed by convention); delta the Huber threshold; prior the motion prior's
    sparse matrix (None: the frames are independent).
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    F, J, D = tracks.shape
    nv = robot.nv
    pos, jac = robot.jacobians(q)
    pred, y = view.apply(pos)
    rn = np.linalg.norm(pred - np.nan_to_num(tracks), axis=-1)
    ww = w * _huber(rn, delta)[1]
    free_view = np.ones(view.n_params, bool)
    Hqq, Hqc, _, Hcc, _ = _normal_equations(view, jac, y, pred - np.nan_to_num(tracks), ww, free, free_view)
    fr = free.reshape(-1).astype(float)
    # a held direction: an identity row and column, cut from the rest (its variance is not reported)
    held = np.einsum("fv,vu->fvu", 1.0 - free, np.eye(nv))
    data_q = Hqq
    Hqq = Hqq + held
    nc = view.n_params
    if view.per_frame:  # one camera per frame, no prior: every frame on its own
        top = np.concatenate([Hqq, Hqc], 2)
        bottom = np.concatenate([Hqc.transpose(0, 2, 1), Hcc], 2)
        Hf = np.concatenate([top, bottom], 1)
        cov = np.linalg.pinv(Hf, hermitian=True)
        var = np.einsum("fvv->fv", cov[:, :nv, :nv])
        p_eff = float(np.einsum("fij,fji->", cov, Hf - np.pad(held, ((0, 0), (0, nc), (0, nc)))))
    else:
        Hdata = sp.block_diag(list(Hqq), format="csr")
        M = sp.csr_matrix((F * nv, F * nv)) if prior is None else sp.diags(fr) @ prior @ sp.diags(fr)
        A = (Hdata + M).tocsc()
        lu = splu(A)
        X = lu.solve(Hqc.reshape(F * nv, nc))  # A^-1 H_qc
        S = Hcc[0] - Hqc.reshape(F * nv, nc).T @ X + 1e-12 * np.eye(nc) * np.trace(Hcc[0])
        S_inv = np.linalg.inv(S)
        m = prior_frames(prior, nv) if prior is not None else 2  # block-tridiagonal in blocks of m frames
        inv_blocks = _block_tridiagonal_inverse_diagonal(*_frame_blocks(A, F, nv, m))
        # per-frame diagonal blocks of A^-1, then the camera's share: (A^-1 Hqc) S^-1 (A^-1 Hqc)'
        blocks = np.stack([inv_blocks[:, i * nv:(i + 1) * nv, i * nv:(i + 1) * nv] for i in range(m)], 1)
        blocks = blocks.reshape(-1, nv, nv)[:F]
        Xf = X.reshape(F, nv, nc)
        cov_qq = blocks + Xf @ S_inv @ Xf.transpose(0, 2, 1)
        var = np.einsum("fvv->fv", cov_qq)
        # p_eff = trace(H^-1 H_data): q blocks, the q-camera coupling twice, the camera block
        cov_qc = -X @ S_inv
        p_eff = float(np.einsum("fij,fji->", cov_qq, data_q)) + 2.0 * float(np.sum(cov_qc * Hqc.reshape(F * nv, nc))) \
            + float(np.trace(S_inv @ Hcc[0]))
    n_obs = D * int((w > 0).sum())
    sigma = _noise_sigma(rn, w) * np.sqrt(n_obs / max(n_obs - p_eff, 1.0))
    std = sigma * np.sqrt(np.maximum(var, 0.0))
    return np.where(free, std, np.nan), float(sigma)


def joint_covariance(robot: RobotKinematics, q: np.ndarray, tracks: np.ndarray, w: np.ndarray, view, free: np.ndarray,
                     delta: float | None, prior=None) -> np.ndarray:
    """(F nv, F nv) covariance of the fitted joint angles q (F, nq) over all frames and joints, frame
    after frame, per unit pixel variance (times ``sigma^2`` of :func:`joint_std`, whose squared
    deviations are its diagonal): the camera(s) marginalised, NaN in the rows and columns of held
    directions. Arguments as for :func:`joint_std`.

    Dense (cubic in F nv): for short sequences, where the correlations between frames matter, such as
    a benchmark asking whether one trial's errors, which share the camera's and the motion prior's,
    are as spread as the model says (:mod:`benchmarks.bench_uncertainty`)."""
    F, J, D = tracks.shape
    nv, N = robot.nv, len(q) * robot.nv
    pos, jac = robot.jacobians(q)
    pred, y = view.apply(pos)
    rn = np.linalg.norm(pred - np.nan_to_num(tracks), axis=-1)
    ww = w * _huber(rn, delta)[1]
    Hqq, Hqc, _, Hcc, _ = _normal_equations(view, jac, y, pred - np.nan_to_num(tracks), ww, free,
                                            np.ones(view.n_params, bool))
    C, nc = len(Hcc), view.n_params
    fr = free.reshape(-1)
    H = np.zeros((N + C * nc, N + C * nc))
    frames = np.arange(F)[:, None] * nv + np.arange(nv)
    H[frames[:, :, None], frames[:, None, :]] = Hqq
    if prior is not None:
        H[:N, :N] += prior.toarray() * np.outer(fr, fr)
    cams = N + np.asarray(view.cam_of)[:, None] * nc + np.arange(nc)  # (F, nc) columns of each frame's camera
    H[frames[:, :, None], cams[:, None, :]] = Hqc
    H[cams[:, :, None], frames[:, None, :]] = Hqc.transpose(0, 2, 1)
    for c in range(C):
        H[N + c * nc:N + (c + 1) * nc, N + c * nc:N + (c + 1) * nc] = Hcc[c]
    keep = np.r_[fr, np.ones(C * nc, bool)]
    cov = np.full((N, N), np.nan)
    cov[np.ix_(fr, fr)] = np.linalg.pinv(H[np.ix_(keep, keep)], hermitian=True)[:fr.sum(), :fr.sum()]
    return cov


# a joint whose unsettled alternatives differ from the reported motion by more (RMS) is ambiguous: the
# accuracy the full-range benchmark asks for (2 degrees RMS). At 5, TALOS's arm had tied alternatives 3-5
# degrees away on four joints, reported observable and 2.6-4.1 degrees off: a fit that fits as well
# differs by more than the claimed accuracy, so the joint is not known to it
AMBIGUOUS_DEG = 2.0
# a joint whose standard deviation times this is more than AMBIGUOUS_DEG is "uncertain": the claim
# "within AMBIGUOUS_DEG" is then made at two standard deviations (about 95 %), not one. A fit's errors
# are correlated over the frames (the static camera, the motion prior), so a joint's RMS error over a
# sequence is about |z| standard deviations, z one Gaussian draw: at one standard deviation a third of
# the joints just under the bar miss it. The UR10 from below (full ranges, 30 frames, seed 31):
# wrist_2 reported with 1.3 degrees, 3.0 off the truth; over 12 noise draws of the same motion its
# deviations held (60 % within one) and 4 of the 12 ended more than 2 degrees RMS off
UNCERTAIN_SIGMAS = 2.0
# an alternative's difference (deg or mm) below this is not named beside an uncertain joint's deviation
# (printed to one decimal it would read "0.0")
NAMED_DIFFERENCE = 0.05


def alternatives_of(robot: RobotKinematics, winner: dict, scored: list[tuple[float, dict]], sigma: float,
                    settled, relative: np.ndarray | None = None) -> list[dict]:
    """The other motions that fit the tracks as well as the reported one (``winner``): of ``scored``
    ((objective, fit) pairs, fits with ``q``), those within the tie tolerance of the lowest objective or
    of the winner's (:data:`chainspace.robot.candidates.TIE_VARIANCES` noise variances ``sigma^2``: a
    likelihood-ratio test), distinct from the winner and from each other
    (:func:`chainspace.robot.candidates._same_motion`, the joints ``relative`` (nv,) to frame 0 compared as
    their change since frame 0).

    Each is ``{"angles": (F, nv), "score": objective above the lowest in noise variances (0: an exact
    tie), "settled_by": the rule that validly set it aside (``settled(fit)``, e.g. the camera side), or
    None when only a guess did}``, best score first."""
    from .candidates import TIE_VARIANCES, _same_motion

    if not scored:
        return []
    lowest = min(s for s, _ in scored)
    # ties with the winner count too: a search that converged further (a restart in the winner's own
    # basin, lower by more than the tolerance) must not push the winner's exact twins out of the tie
    own = next((s for s, r in scored if r is winner), lowest)
    var = max(sigma, 1e-12) ** 2
    out: list[dict] = []
    seen = [winner["q"]]
    for s, r in sorted(scored, key=lambda sr: sr[0]):
        if r is winner or s - max(lowest, own) > TIE_VARIANCES * var or \
                any(_same_motion(robot, r["q"], o, relative) for o in seen):
            continue
        seen.append(r["q"])
        out.append({"angles": robot.angles(r["q"]), "score": float((s - lowest) / var), "settled_by": settled(r)})
    return out


def ambiguous_joints(robot: RobotKinematics, angles: np.ndarray, alternatives: list[dict],
                     judged: np.ndarray, relative: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(nv,) joints whose unsettled alternatives differ from ``angles`` (F, nv) by more than
    :data:`AMBIGUOUS_DEG` RMS over the frames (wrapped for turning joints; prismatic joints: that
    many millimetres), among ``judged`` (nv,), joints seen ``relative`` (nv,) to frame 0 compared as their
    change since frame 0; and the largest such RMS
    difference per joint (degrees, or mm for prismatic joints; 0 without alternatives)."""
    worst = np.zeros(robot.nv)
    for alt in alternatives:
        if alt["settled_by"]:
            continue
        d = _relative_difference(robot, alt["angles"], angles, relative)
        rms = np.sqrt(np.mean(d ** 2, axis=0)) * np.where(robot.prismatic_v, 1000.0, np.degrees(1.0))
        worst = np.maximum(worst, rms)
    return (worst > AMBIGUOUS_DEG) & judged, worst


def uncertain_joints(robot: RobotKinematics, std: np.ndarray, judged: np.ndarray,
                     apart: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(nv,) joints, among ``judged`` (nv,), whose standard deviations std (F, nv; radians, metres for
    prismatic joints, NaN where held), RMS over the frames, times :data:`UNCERTAIN_SIGMAS`, plus ``apart``
    (nv,; the largest RMS difference of an unsettled alternative that fits as well, :func:`ambiguous_joints`;
    degrees or mm, none given: 0), are more than :data:`AMBIGUOUS_DEG` degrees (millimetres for prismatic
    joints); and that RMS per joint (degrees or mm; NaN where none is known).

    Why: a joint the tracks pin down only to several degrees is not known to the accuracy claimed, even
    when nothing ties with the fit. The Panda from 20 degrees below its base (full ranges, 30 frames,
    seed 0): panda_joint7, which turns the hand about the axis its tracked points lie near (only the
    fingers, a few centimetres off it, show it), reported observable with a standard deviation of
    1.2-3.5 degrees over the frames (2.2 RMS) and 3.7 degrees RMS off the truth; no other basin (a
    refit from the true motion ends at the fit's), no other branch, a good fit (noise 0.97 px on 1 px
    tracks): the tracks alone do not say more.

    Why ``apart``: an alternative that fits as well may be the truth, and the truth lies within the
    standard deviations of it, so the reported joint is known to that difference plus them (the triangle
    inequality). Over the full-range benchmark's pinhole seeds 54-61 and weak seeds 52-59 (512 runs, 2,605
    judged joints) the standard deviations held (73 % of the errors within one, 99.4 % within two), and of
    the four joints more than 2 degrees off and reported, two were this case: the Panda from below (seed
    61) panda_joint1, 0.81 degrees, an alternative 1.1 degrees away, 2.09 off; the Z1 from below (seed 59)
    joint2, 0.66 degrees, an alternative 1.59 away, 2.51 off. The rule flags 13 further joints there that
    were within 2 degrees; three standard deviations alone would have flagged 172 such and caught only the
    Panda's."""
    known = np.isfinite(std).any(0)
    ms = np.nanmean(np.where(known, std, 0.0) ** 2, axis=0)
    spread = np.where(known, np.sqrt(ms) * np.where(robot.prismatic_v, 1000.0, np.degrees(1.0)), np.nan)
    near = 0.0 if apart is None else np.asarray(apart, float)
    return judged & known & (UNCERTAIN_SIGMAS * np.nan_to_num(spread) + near > AMBIGUOUS_DEG), spread


# a tracked point whose median residual exceeds this many times the median the measured noise gives
# (sigma sqrt(2 ln 2), the median of a 2D Gaussian error's length) is not explained by the fit
POOR_FIT_RATIO = 2.0
POOR_FIT_MIN_FRAMES = 5  # a point seen in fewer frames is not judged (its median is too noisy)
# and a point whose median over any POOR_FIT_WINDOW consecutive sightings exceeds POOR_FIT_WINDOW_RATIO
# times the noise's: a path that leaves the true one for the last or first few frames (more than half a
# window missed; three outlying detections in a row are not). With 1 px noise, a window's median of 7
# residual lengths passes 3 times the noise's (3.5 px) with a chance of about 5e-10
POOR_FIT_WINDOW = 7
POOR_FIT_WINDOW_RATIO = 3.0
# a median residual below this share of the tracks' extent is no misfit, whatever its ratio: on
# noise-free tracks the measured noise is rounding (1e-12 px), and so is every residual it divides; on
# rendered markers a detection bias of 0.02-0.03 px per marker, constant over the frames, is twice the
# measured noise of 0.025 px (the demo: joint_a1 and a2 flagged with 0.2 degrees of error); a wrong
# basin misses by pixels (the double pendulum's tip: about 3 px on a robot some 500 px across)
POOR_FIT_FLOOR = 1e-3
# the tracks' own jitter (:func:`track_jitter`) times this is a yardstick too (so a point is poorly
# fitted beyond POOR_FIT_RATIO x JITTER_SLACK = 20 times it): slack for a tracker's errors that persist
# over frames (a 2D tracker drifts; the jitter sees only the part that changes from frame to frame) and
# for the motion's own change of acceleration, which the jitter counts as noise. Wrong basins miss by
# far more (the close-range milling arm: 43-105 times its jitter)
JITTER_SLACK = 10.0


def _point_noise(sigma: float, jitter: float) -> float:
    """The pixel noise per coordinate that the point rules (:func:`poor_fit_joints`, :func:`base_offsets`)
    judge by: the measured ``sigma``, or :data:`JITTER_SLACK` times the tracks' own ``jitter`` where that
    is lower (NaN: not used), since a wrong basin pulls the measured noise up with it."""
    return min(sigma, JITTER_SLACK * jitter) if np.isfinite(jitter) else sigma


def track_jitter(tracks: np.ndarray, w: np.ndarray) -> float:
    """The tracks' own noise, pixels per coordinate, measured without any fit: a robust standard
    deviation of the second differences over three consecutive frames where a point is seen, over
    sqrt(6) (white noise of sigma gives second differences of sigma sqrt(6)). A smooth motion adds
    little at video rates (1 px noise on the milling arm's 300-frame motion: 1.10 px); NaN when no
    point is seen in three consecutive frames.

    Why: the measured noise that :func:`poor_fit_joints` compares with comes from the fit's own
    residuals, so a fit in a wrong basin that misses every point inflates it with them. The milling
    arm at close range (300 frames, 1 px, nearest point 0.3 m from a 90 degree lens): every start of
    the perspective fit came from a weak-perspective fit 30-130 degrees off, the fit missed its points
    by 56-136 px (median), its measured noise was 100 px, and joints 2 and 3 (79 and 46 degrees off)
    were reported observable. The tracks' jitter there is 1.1 px."""
    x = np.asarray(tracks, float)
    seen = (np.asarray(w) > 0) & np.isfinite(x).all(-1)
    if len(x) < 3:
        return float("nan")
    ok = seen[2:] & seen[1:-1] & seen[:-2]
    d2 = np.abs((x[2:] - 2 * x[1:-1] + x[:-2])[ok]).ravel()
    return 1.4826 * float(np.median(d2)) / np.sqrt(6.0) if d2.size else float("nan")


# a weak-perspective fit that the user asked for by giving no camera (assess_fit's ``camera_assumed``) is
# poor as a whole where its typical tracked point lies this many times further off (median) than the
# tracks' own jitter allows a right model (see camera_misfit)
CAMERA_MISFIT_RATIO = 1.25


def camera_misfit(rn: np.ndarray, w: np.ndarray, jitter: float) -> tuple[float, float]:
    """(ratio, typical): the typical tracked point's median residual length ``typical`` (px; the median
    over the points seen in :data:`POOR_FIT_MIN_FRAMES` frames or more of each one's median), and its
    ratio to ``jitter sqrt(2 ln 2)``, the median residual length a right model leaves on tracks of that
    jitter (:func:`track_jitter`). About 0.9 where the model matches the footage (the fit's own degrees
    of freedom take a little of the noise); NaN without a jitter or a judged point.

    Why: a weak-perspective fit of footage from a camera within a few robot reaches misses every point
    alike, so no point stands out from the typical one (:func:`poor_fit_joints` sees nothing), while its
    joints are 5-140 degrees off (the UR10, Panda and milling arm filmed by ``synthesize``'s phone-like
    camera, 60 frames: typical point 1.4-6 times the jitter's, against 0.9 through a weak camera)."""
    typical = _point_medians(rn, w)[2]
    if not np.isfinite(typical) or not np.isfinite(jitter) or jitter <= 0:
        return float("nan"), float("nan")
    return typical / (jitter * np.sqrt(2 * np.log(2))), typical


def _point_medians(rn: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Each tracked point's median residual length (J,; 0 where never seen), whether it is judged (seen
    in :data:`POOR_FIT_MIN_FRAMES` frames or more), and the typical point's: the median of the judged
    points' medians (NaN when none is judged)."""
    seen = (w > 0) & np.isfinite(rn)
    n = seen.sum(0)
    med = np.array([np.median(rn[seen[:, j], j]) if n[j] else 0.0 for j in range(rn.shape[1])])
    judged = n >= POOR_FIT_MIN_FRAMES
    return med, judged, float(np.median(med[judged])) if judged.any() else float("nan")


def _window_medians(rn: np.ndarray, w: np.ndarray, size: int = POOR_FIT_WINDOW) -> np.ndarray:
    """Each tracked point's largest median residual length (J,; px) over ``size`` consecutive sightings
    (0 where seen fewer times)."""
    from numpy.lib.stride_tricks import sliding_window_view

    seen = (w > 0) & np.isfinite(rn)
    return np.array([np.median(sliding_window_view(rn[seen[:, j], j], size), axis=-1).max()
                     if seen[:, j].sum() >= size else 0.0 for j in range(rn.shape[1])])


def poor_fit_joints(robot: RobotKinematics, q: np.ndarray, rn: np.ndarray, w: np.ndarray, sigma: float,
                    extent: float = 0.0, jitter: float = np.nan) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Joints (nv,) that move a tracked point the fit does not explain or lie beyond it in the chain, the
    names of those points, and each point's ratio (J,) of its median residual (over the sequence or, where
    larger, over a window of it) to the noise's.

    rn (F, J) residual lengths (px) of the fit q (F, nq), w (F, J) weights, sigma the measured pixel
    noise per coordinate. A point is poorly fitted when it is seen in at least
    :data:`POOR_FIT_MIN_FRAMES` frames and the median of its residual lengths exceeds
    :data:`POOR_FIT_RATIO` times ``sigma sqrt(2 ln 2)`` (a median, so that a few outlying detections do
    not count; a wrong basin misses a point in most frames), or the median over some
    :data:`POOR_FIT_WINDOW` consecutive sightings exceeds :data:`POOR_FIT_WINDOW_RATIO` times it (a path
    that leaves the true one for a few frames), and :data:`POOR_FIT_FLOOR` times ``extent``, the tracks'
    extent (px; 0: no floor). Where the typical point's median or
    :data:`JITTER_SLACK` times the tracks' own ``jitter`` (:func:`track_jitter`, px per coordinate; NaN:
    not used) is lower than the measured noise, that is the yardstick: a wrong basin pulls the
    measured noise up with it. A poorly fitted point that no joint moves (on the base), or poorly fitted
    points that no one joint moves all of (on two branches of a tree), put the camera in doubt, and with
    it every joint.

    Why: the likelihood-ratio tests compare the fit with the motions the fit's searches reached; when
    every search ends in a wrong basin (a small robot near the camera, seen from below: the double
    pendulum's tip 2.5 times further off than its other points in most frames, joint1 166 degrees
    off, squared residuals 640 px^2 where the true motion's basin has 148), nothing ties with the
    winner, but the fit still does not explain the tracks, and its joints are not known. The Solo12
    (full ranges, seed 0): measured noise 3.6-3.9 px on 1 px tracks, joints up to 120 degrees off. And the
    Solo12 through a pinhole camera from below (seed 58): the right leg's path left the true one over the
    last 8 of 30 frames (hip and knee 55 degrees off in the last), its knee and foot fitted as well as the
    other points in the median over the sequence, the fit's squared residuals 155 noise variances above
    the true motion's, and every joint reported observable."""
    med, judged, typical = _point_medians(rn, w)
    # against the noise, or the typical point's median where that is lower (the measured noise is a
    # median over every residual, which a badly fitted point pulls up)
    typical = typical if judged.any() else np.inf
    noise = _point_noise(sigma, jitter)
    yardstick = max(min(noise * np.sqrt(2 * np.log(2)), typical), 1e-12)
    spell = _window_medians(rn, w)  # (a wrong path over a few frames only: the sequence's median misses it)
    missed = (med > POOR_FIT_RATIO * yardstick) & (med > POOR_FIT_FLOOR * extent) | \
        (spell > POOR_FIT_WINDOW_RATIO * yardstick) & (spell > POOR_FIT_FLOOR * extent)
    ratio = np.maximum(med, spell) / yardstick
    bad = judged & missed
    if not bad.any():
        return np.zeros(robot.nv, bool), [], ratio
    moves = _point_movers(robot, q)
    joints = moves[bad].any(0)
    # missed points that no one joint moves (a base point, which no joint moves; points on two legs of a tree): no
    # one wrong path explains them all, but the camera they share does, and then every joint is in doubt. The
    # Solo12 through a weak camera from above (full ranges, seed 85): points of the front and hind left legs 12
    # times further off than the noise allows, the front right leg fitting its own tracks 79-121 degrees off and
    # reported observable; a fit from the true points ended no better (the search missed the true basin: 6243
    # px^2 where the noise gives about 1000)
    if not moves[bad].all(0).any():
        joints[:] = True
    # and the joints beyond a missed point: each turns its link relative to a parent the fit placed wrong
    # (every point such a joint moves is moved by every joint that moves the missed point). The TALOS arm
    # from below (pinhole, full ranges, seed 57): arm_left_4_link 13.6 times the noise off, joints 2-3
    # flagged, joints 4-7 3-43 degrees off and reported observable
    inside = (~moves[:, :, None] | moves[:, None, :]).all(0)  # (nv, nv): every point k moves, a moves too
    for j in np.flatnonzero(bad & moves.any(1)):
        joints |= ~moves[j] & moves.any(0) & inside[:, moves[j]].all(1)
    return joints, [robot.chain.joints[j] for j in np.flatnonzero(bad)], ratio


# a base point (one that no joint moves: through the static camera its image is one pixel in every frame)
# whose fitted image lies further from the median of its sightings than this many standard errors of that
# median (1.2533 sigma / sqrt(n) per coordinate) puts the camera in doubt, and with it every joint: on a
# right fit such an offset has a chance of exp(-z^2 / 2), 4e-6 at 5
BASE_OFFSET_Z = 5.0


def base_offsets(robot: RobotKinematics, q: np.ndarray, view, tracks: np.ndarray, w: np.ndarray, sigma: float,
                 extent: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The base points the fit misses on average (J,) bool, each point's offset (J,; px: the length of the
    per-coordinate median of its residuals over its sightings; 0 for a moving point, or one seen in fewer
    than :data:`POOR_FIT_MIN_FRAMES` frames) and that offset in standard errors of the median under pixel
    noise ``sigma`` (J,). A base point is missed where that is more than :data:`BASE_OFFSET_Z` and the
    offset more than :data:`POOR_FIT_FLOOR` times the tracks' ``extent`` (px). ``view``: the fit's one
    static camera (a camera per frame: nothing is judged); tracks (F, J, 2) as fitted, weights w (F, J).

    Why: the lengths of the residuals (:func:`poor_fit_joints`) hide an offset of about the noise's size,
    while the median of thirty sightings pins a still point's image down to a fifth of it. The TALOS arm
    through a pinhole camera from above (full ranges, seed 61): its second base point fitted 1.4 px off the
    mean of its sightings (7 standard errors of that mean; median residual length 1.9 px, 1.8 times the
    noise's), arm_left_2 19 degrees off and reported observable, arm_left_3 177. Over the full-range
    benchmark's pinhole seeds 54-63 (320 runs) a base point more than 6 standard errors of its mean off
    was found in 11 runs, each with joints 20-170 degrees off: that one and 10 already flagged; no weak
    run came near (seeds 52-56, 83 runs: at most 2.2). With this rule, those 320 runs and the weak seeds
    52-61 (320) refitted: two changed, that TALOS arm's, and a Solo12 from above (seed 60) whose legs,
    50-91 degrees off, were flagged already, two more of its joints flagged; the rest identical."""
    J = tracks.shape[1]
    none = np.zeros(J, bool), np.zeros(J), np.zeros(J)
    if getattr(view, "per_frame", False) or not np.isfinite(sigma) or sigma <= 0:
        return none
    still = ~_point_movers(robot, q).any(1)
    seen = (w > 0) & np.isfinite(tracks).all(-1)
    n = seen.sum(0)
    judged = still & (n >= POOR_FIT_MIN_FRAMES)
    if not judged.any():
        return none
    pred = view.apply(robot.positions(q))[0]
    offset = np.zeros(J)
    for j in np.flatnonzero(judged):
        offset[j] = np.linalg.norm(np.median(pred[seen[:, j], j] - tracks[seen[:, j], j], axis=0))
    z = offset * np.sqrt(n) / (1.2533 * sigma)
    return judged & (z > BASE_OFFSET_Z) & (offset > POOR_FIT_FLOOR * extent), offset, z


def assess_fit(robot: RobotKinematics, winner: dict, scored: list[tuple[float, dict]], var: float,
               tracks: np.ndarray, w: np.ndarray, prior, blind: np.ndarray, gauge: np.ndarray, wrong_side,
               side_why: str, search: bool = False, camera_assumed: bool = False) -> dict:
    """What the fit knows and does not: ``q_std`` (F, nv) (NaN where a joint is held: not observable,
    or unseen without the motion prior; 0 for a joint seen relative to frame 0, in frame 0),
    ``noise_px`` (the measured pixel noise), ``alternatives`` (:func:`alternatives_of`; ``scored``
    holds (objective, fit) pairs, objectives in units where a noise variance is ``var``), ``ambiguous``
    (nv,: tied, poorly fitted or uncertain; every joint where the solver stopped before it converged),
    ``ambiguity_deg`` (nv,), ``notes`` (sentences for the fit's message), ``reasons`` (nv strings: why
    each flagged joint is flagged, "" for the rest) and ``poor`` (nv,: the poorly fitted joints among them).

    ``winner``: the reported fit (``out``, ``q``, ``free``/``free_prior``, ``delta``); ``prior``: the
    motion prior it was smoothed with, or None; ``wrong_side(fit)``: the camera-side rule, True where
    it validly sets a fit aside; ``side_why``: why that rule does not apply here ("" when it does).
    ``search``: also look beyond the fit's candidates (:func:`_exact_flips` refitted and
    :func:`_other_branch`, :func:`_shaken`): the ``search_ties`` of ``fit_joint_angles`` (on by
    default; it costs several fits, the restarts of a long sequence on sampled frames).
    ``camera_assumed``: the camera model was not given but assumed (weak perspective, no intrinsics or
    image size): a fit that misses its points as a whole (:func:`camera_misfit` above
    :data:`CAMERA_MISFIT_RATIO`) then has every joint poorly fitted."""
    q, view = winner["out"][0], winner["out"][1]
    rel = gauge & ~blind
    free = (winner["free_prior"] if prior is not None else winner["free"]).copy()
    free[0, rel] = False  # a turn of the camera imitates these: reported relative to frame 0, held there
    try:
        std, noise = joint_std(robot, q, tracks, w, view, free, winner["delta"], prior)
    except (np.linalg.LinAlgError, RuntimeError, ValueError):  # a singular system: nothing to say
        std, noise = np.full((len(q), robot.nv), np.nan), float("nan")
    std[0, rel] = 0.0  # by definition: the joint is reported as its change since frame 0
    std[:, blind] = np.nan
    sigma = float(np.sqrt(var))

    def settled(x: dict) -> bool:  # the camera-side rule sets this fit aside (it knows where its camera is)
        return "down" in x and bool(wrong_side(x))

    scored = list(scored) + _exact_flips(robot, winner, scored, tracks, w, prior, free, sigma, search)
    if search:
        for base in [winner] + _runners_up(robot, winner, scored, SHAKE_RUNNERS_UP):
            scored += _shaken(robot, base, winner, scored, tracks, w, prior, free, ~rel, var, settled)
    alts = alternatives_of(robot, winner, scored, sigma, lambda x: "camera side" if settled(x) else None, rel)
    ambiguous, worst = ambiguous_joints(robot, robot.angles(q), alts, ~blind, rel)
    notes = []
    seen = np.isfinite(tracks).all(-1)
    extent = float(np.ptp(tracks[seen], axis=0).max()) if seen.any() else 0.0
    jitter = track_jitter(tracks, w)
    poor, points, ratio = poor_fit_joints(robot, q, winner["out"][2], w, noise, extent, jitter) \
        if np.isfinite(noise) else (np.zeros(robot.nv, bool), [], None)
    poor &= ~blind
    misfit, typical = camera_misfit(winner["out"][2], w, jitter) if camera_assumed else (float("nan"), 0.0)
    whole = bool(misfit > CAMERA_MISFIT_RATIO and typical > POOR_FIT_FLOOR * extent)  # (noise-free: rounding)
    based, offset, z_off = base_offsets(robot, q, view, tracks, w, _point_noise(noise, jitter), extent)
    if whole or based.any():
        poor = ~blind
    near = np.where(ambiguous, 0.0, worst)  # a tied joint is flagged for its tie: no second reason
    uncertain, spread = uncertain_joints(robot, std, ~blind, near)
    # a winner whose solver stopped short of a minimum is no answer the tracks chose: over the full-range
    # benchmark's runs (docs/benchmarks.md) every one that stopped so lay in a wrong basin, 40-153 degrees
    # off, and two of them (the Kinova from above, the TALOS arm from below, weak camera, seeds 54-55)
    # said so only in the message's first words, with joints 92-101 degrees off reported observable
    stalled = ~blind & (not bool(np.all(winner["out"][4])))
    unit = np.where(robot.prismatic_v, "mm", "deg")
    # (no note holds "; ": the fit's message joins its notes with it, and the perspective fit splits them again)
    base_why = "the base point(s) " + ", ".join(f"{robot.chain.joints[j]} ({offset[j]:.2g} px, {z_off[j]:.0f} "
                                                "standard errors)" for j in np.flatnonzero(based)) \
        + " lie off the median of their sightings by more than the noise averaged over them allows"
    if whole:
        notes.append(f"poor fit: {', '.join(robot.joint_names[k] for k in np.flatnonzero(poor))}: the tracked "
                     f"points are fitted {typical:.2g} px off (median), {misfit:.1f} times what the tracks' own "
                     f"jitter ({jitter:.2g} px from frame to frame) leaves a right model: the weak-perspective "
                     "camera this fit assumes (or the robot model) does not explain the tracks")
    elif based.any():
        notes.append(f"poor fit: {', '.join(robot.joint_names[k] for k in np.flatnonzero(poor))}: {base_why}, so "
                     "the camera is placed wrong and the reported motion is not known to be right")
    elif poor.any():
        notes.append(f"poor fit: {', '.join(robot.joint_names[k] for k in np.flatnonzero(poor))}: the tracks of "
                     f"{', '.join(points)} are fitted {ratio.max():.1f} times further off (median, over the "
                     f"sequence or {POOR_FIT_WINDOW} sightings in a row) than the noise "
                     f"({noise:.2g} px, the tracks' own jitter {jitter:.2g} px) or the typical tracked point allow, "
                     "so the fit ended in a wrong basin or the model does not match the robot, and the reported "
                     "motion is not known to be right")
    if stalled.any():
        notes.append(f"not converged: {', '.join(robot.joint_names[k] for k in np.flatnonzero(stalled))}: the "
                     "solver stopped before it reached a minimum of its objective, so the reported motion is not "
                     "known to be right (in the benchmarks such fits were in a wrong basin)")
    if ambiguous.any():  # the tied joints only: a poorly fitted one has its own note above
        names = [f"{robot.joint_names[k]} ({worst[k]:.0f} {unit[k]} RMS)" for k in np.flatnonzero(ambiguous)]
        notes.append(f"ambiguous: {', '.join(names)}: {len(alts)} other motion(s) fit the tracks as well "
                     f"(within {_tie_variances():g} noise variances) and differ there by more than "
                     f"{AMBIGUOUS_DEG:g} degrees RMS: the reported one is a guess (fit.alternatives)"
                     + (f" ({side_why})" if side_why else ""))
    if uncertain.any():
        names = [f"{robot.joint_names[k]} ({spread[k]:.1f} {unit[k]}" + (f", an alternative {near[k]:.1f} {unit[k]} "
                 "away" if near[k] >= NAMED_DIFFERENCE else "") + ")" for k in np.flatnonzero(uncertain)]
        notes.append(f"uncertain: {', '.join(names)}: {UNCERTAIN_SIGMAS:g} reported standard deviations (RMS over "
                     f"the frames, fit.q_std), plus the difference from another motion that fits as well where "
                     f"there is one, are more than {AMBIGUOUS_DEG:g} degrees ({AMBIGUOUS_DEG:g} mm for a sliding "
                     "joint): the tracks pin these joints down no better: reported, not trusted")
    # one reason per joint ("" where none), each naming only what concerns that joint
    reasons = ["; ".join(why for flag, why in (
        (poor[k], f"poor fit: the tracked points are fitted {misfit:.1f} times further off (median) than the "
                  "tracks' jitter allows (the assumed weak-perspective camera)" if whole else
                  f"poor fit: {base_why} (the camera is placed wrong)" if based.any() else
                  f"poor fit: the tracks of {', '.join(points)} are fitted {ratio.max() if poor.any() else 0:.1f} "
                  f"times further off (median, over the sequence or {POOR_FIT_WINDOW} sightings in a row) than "
                  "the noise or the typical tracked point allow"),
        (stalled[k], "not converged: the solver stopped before it reached a minimum of its objective"),
        (ambiguous[k], f"tie: {len(alts)} other motion(s) fit the tracks as well and differ here by up to "
                       f"{worst[k]:.0f} {unit[k]} RMS (fit.alternatives)"),
        (uncertain[k], f"uncertain: standard deviation {spread[k]:.1f} {unit[k]} (RMS over the frames, fit.q_std): "
                       f"{UNCERTAIN_SIGMAS:g} of them" + (f", plus the {near[k]:.1f} {unit[k]} by which a motion "
                       "that fits as well differs here (fit.alternatives)," if near[k] >= NAMED_DIFFERENCE else "")
                       + f" exceed the {AMBIGUOUS_DEG:g} {unit[k]} claimed")) if flag)
        for k in range(robot.nv)]
    ambiguous = ambiguous | poor | uncertain | stalled
    return dict(q_std=std, noise_px=noise, alternatives=alts, ambiguous=ambiguous, ambiguity_deg=worst, notes=notes,
                reasons=reasons, poor=poor)


def _scorer(robot: RobotKinematics, winner: dict, scored: list[tuple[float, dict]], tracks: np.ndarray,
            w: np.ndarray, prior):
    """``score(q, rn=None)``: a motion's objective on the scale of ``scored`` (the winner's entry plus the
    difference of the two objectives under the winner's camera: the same robust loss, plus the motion
    prior when there is one), so that a tie found by a search is a tie. ``rn`` (F, J) px: its
    residuals, when a refit already has them."""
    view, delta = winner["out"][1], winner["delta"]

    def objective(qa, rn=None):
        if rn is None:
            rn = np.linalg.norm(view.apply(robot.positions(qa))[0] - np.nan_to_num(tracks), axis=-1)
        return _fit_objective(robot, qa, rn, w, delta, prior)

    base = next((s for s, x in scored if x is winner), min((s for s, _ in scored), default=0.0))
    own = objective(winner["out"][0])
    return lambda qa, rn=None: base + objective(qa, rn) - own


# a twin's points match the motion's to this share of the robot's size (exact: URDFs round their angles);
# a near twin's, to this (a start to refit: the offsets along an arm leave its twins centimetres apart)
EXACT_TWIN_SIZE = 1e-4
NEAR_TWIN_SIZE = 0.05


def _exact_flips(robot: RobotKinematics, winner: dict, scored: list[tuple[float, dict]], tracks: np.ndarray,
                 w: np.ndarray, prior, free: np.ndarray, sigma: float, refit: bool = True) -> list[tuple[float, dict]]:
    """The winner's twins, scored as ``scored`` is: per link, the motion with that link and everything
    beyond it mirrored in depth (and the joints from each one on started from the other side of the
    rest pose), fitted to the winner's points frame by frame
    (:func:`chainspace.robot.candidates._depth_flips`), then to the tracks under the winner's camera
    (a few Levenberg-Marquardt steps per frame, the camera held). Where such a motion puts the tracked
    points where the winner does, only the rest-pose rule chose between them (a planar wrist or leg
    mirrored in depth): it is an alternative. Scored against the winner's objective (the same robust
    loss, plus the motion prior when there is one), so a tie found here is a tie.

    Why the refit: under weak perspective a depth mirror projects exactly as the winner does, but under
    a pinhole camera it is off by a few pixels until its joints are adjusted to the tracks; scored as
    mirrored it lost by far more than the tie tolerance, and the xArm7's wrist (joint5 127 degrees off,
    the wrong branch fitting the tracks as well as the true one) was reported observable. ``refit``
    False (the default assessment, cheap): the mirrored motions are scored as they are."""
    from .candidates import _depth_flips, _far_depth_flips, _same_motion
    from .solver import _sequence_lm, _smooth_lm

    q, view, delta = winner["out"][0], winner["out"][1], winner["delta"]
    if getattr(view, "per_frame", False) and prior is not None:
        return []

    score = _scorer(robot, winner, scored, tracks, w, prior)
    twins = _wrist_twins(robot, q, free)  # exact under any camera: scored as they are
    # exact with the camera moved as the scene is: the winner's own residuals
    moved = [(score(m, winner["out"][2]), {"q": m}) for m in _wrist_twins(robot, q, free, moved=True)]

    def refitted(motions: list[np.ndarray]) -> list[tuple[float, dict]]:
        """The distinct motions (many links give the same twin) fitted to the tracks under the winner's
        camera, scored."""
        distinct: list[np.ndarray] = []
        for m in motions:
            if not any(_same_motion(robot, m, o) for o in distinct + [q]):
                distinct.append(robot.continuous(m))
        if not distinct:
            return []
        F, K = len(q), len(distinct)
        if prior is None:  # frame by frame under the winner's camera, all twins at once
            idx = np.tile(np.arange(F), K)
            qs, _, rn, _, _, _ = _sequence_lm(robot, np.concatenate(distinct), tracks[idx], w[idx], view.take(idx),
                                              free[idx], np.zeros(view.n_params, bool), 20, 1e-8, delta)
            qs, rn = qs.reshape(K, F, -1), rn.reshape(K, F, -1)
        else:  # smoothed as the winner was (a path refitted frame by frame is rough, which the prior charges)
            step = _sample_step(F)
            if step > 1:  # a long sequence: only the motions that tie on sampled frames are refitted on all
                tied = _tied_on_samples(robot, winner, distinct, tracks, w, prior, free, sigma ** 2, step)
                distinct = [m for m, t in zip(distinct, tied) if t]
                if not distinct:
                    return []
            ones = np.ones(view.n_params, bool)
            fits = map_tasks(robot, lambda m: _smooth_lm(robot, m, tracks, w, view, free, ones, 20, 1e-8, delta, prior),
                             distinct)
            qs, rn = np.stack([f[0] for f in fits]), np.stack([f[2] for f in fits])
        return [(score(qs[k], rn[k]), {"q": qs[k]}) for k in range(len(qs))]

    flips = _depth_flips(robot, q, view, free)
    # far flips are whole other paths, not the winner's points moved: smoothed as the winner was even
    # here (scored as mirrored, the Panda's truth lost by 211 noise variances; smoothed, it ties)
    far = _far_depth_flips(robot, q, view, free)
    if not refit:  # scored as mirrored: exact under weak perspective, a few pixels off under a pinhole
        return moved + [(score(m), {"q": m}) for m in twins + flips] + refitted(far)
    # and the best other continuous branch (_other_branch), refined and scored alike
    return moved + [(score(m), {"q": m}) for m in twins] + \
        refitted(flips + far + [b["q"] for b in _other_branch(robot, winner, tracks, w, free, sigma, flips)])


def _wrist_twins(robot: RobotKinematics, q: np.ndarray, free: np.ndarray, moved: bool = False, *, run: int = 1,
                 tol: float = EXACT_TWIN_SIZE) -> list[np.ndarray]:
    """Motions (F, nq) that put every tracked point exactly where q (F, nq) does, by the Euler-angle
    twin of three successive turning joints: (a + pi, d - b, c + pi) with d = 0 or pi (ZYZ and ZYX-like
    axes) or twice the middle angle at which the outer axes line up (:func:`_twin_offsets`), each joint
    moved by whole turns into its limits. Only twins within the limits,
    moving only free joints (``free`` (F, nv)), whose points match q's to ``tol`` of the robot's size in
    every frame are returned (URDFs round their angles: the xArm7's -1.5708 for -pi/2 leaves its
    shoulder twin 1.3e-6 of its size apart, and a weak-camera fit of the twin went unreported).

    Why: a wrist whose tracked points lie on its axes (the Kinova j2s6s200's, the wrist of most 6-axis
    arms) shows the same points in both, in every frame and under any camera; the depth flips and the
    per-frame IK searches did not reach it (Kinova from below, seed 0: joints 4-6 180 / 121 / 178
    degrees off, reported observable, the true motion's squared residuals equal to the winner's).

    ``moved``: instead, the twins of three joints whose first is held in frame 0 only (seen relative to
    frame 0, the camera's turn standing in for it) that put every point where q does after one rigid
    motion of the whole sequence: with the camera moved alike they show the same image. A shoulder (the
    Panda's joints 1-3 as (a, -b, c + pi): the twin (a + pi, -b, c + pi) turned back half a turn about
    the base axis, the first joint's value kept where the fit holds it), seen by a static camera.
    Through a weak camera over its full ranges the Panda was reported observable in such a twin of the
    truth, joints 2 and 3 94 and 180 degrees off (seed 20 from above).

    ``run``: the middle of the pattern is that many successive joints, (a + pi, d - b, -c, ..., e + pi):
    an arm reaching over its shoulder, its first joint half a turn on and the parallel shoulder and elbow
    mirrored (:func:`_near_twins`)."""
    a = robot.angles(q)
    pos = robot.positions(q)
    size = max(float(np.ptp(pos.reshape(-1, 3), axis=0).max()), 1e-9)
    relative = ~free[0] & free[1:].all(0) if len(q) > 1 else np.zeros(robot.nv, bool)
    out: list[np.ndarray] = []
    for k in range(robot.nv - 1 - run):
        last = k + run + 1
        # a last joint held in every frame (no tracked point moves with it) keeps its value: its half
        # turn would move nothing (the xArm7's wrist, joint7 unseen, ended 180 and 163 degrees off on
        # joints 5 and 6, unreported)
        last_blind = not free[:, last].any()
        held = (free[:, k:last].all() if not moved else relative[k] and free[:, k + 1:last].all()) and \
            (free[:, last].all() or last_blind)
        if not (robot.turns_v[k:last + 1].all() and held):
            continue
        for offset in _twin_offsets(robot, a[0], k, last_blind, tol * size, run):
            # moved: the camera's turn takes the first joint's half turn
            b = _twin_angles(a, k, run, offset, last_blind, first_turned=not moved)
            for v in range(k, last + 1):  # whole turns into the limits (per frame: a twin need not be continuous)
                lo, hi = robot.lower_v[v], robot.upper_v[v]
                if np.isfinite(lo):
                    b[:, v] += 2 * np.pi * np.ceil(np.maximum(lo - b[:, v] - 1e-9, 0.0) / (2 * np.pi))
                if np.isfinite(hi):
                    b[:, v] -= 2 * np.pi * np.ceil(np.maximum(b[:, v] - hi - 1e-9, 0.0) / (2 * np.pi))
            if ((b < robot.lower_v - 1e-9) | (b > robot.upper_v + 1e-9)).any():
                continue
            qb = robot.from_angles(b)
            pb = robot.positions(qb)
            if moved:  # the one rigid motion that brings the twin's points onto q's, then what it leaves
                _, R, t = similarity_align(pb, pos, scale=False)
                pb = pb @ R.T + t
            if np.abs(pb - pos).max() < tol * size:
                out.append(robot.continuous(qb))
    return out


def _twin_angles(a: np.ndarray, k: int, run: int, d: float | np.ndarray, last_blind: bool,
                 first_turned: bool = True) -> np.ndarray:
    """The angles a (F, nv) in the twin pattern of :func:`_wrist_twins` at joints k .. k + run + 1: the
    first half a turn on (where ``first_turned``), the first middle joint at d - b (d (F,) or a number),
    the others negated, the last half a turn on (kept where ``last_blind``)."""
    b = a.copy()
    b[:, k] += np.pi if first_turned else 0.0
    b[:, k + 1] = d - a[:, k + 1]
    b[:, k + 2:k + run + 1] = -a[:, k + 2:k + run + 1]
    b[:, k + run + 1] += 0.0 if last_blind else np.pi
    return b


def _twin_offsets(robot: RobotKinematics, a0: np.ndarray, k: int, last_blind: bool, tol: float,
                  run: int = 1) -> list[float]:
    """The constants d (rad) for which the first middle joint of the pattern at joints k .. k + run + 1
    (:func:`_twin_angles`) at d - b, the outer two turned by half a turn (the last kept where
    ``last_blind``), puts the tracked points of the pose a0 (nv,) back up to one rigid motion (within
    ``tol`` metres). Where the outer axes meet at b = 0, d is 0 or pi; where they line up at b0, 2 b0
    (a wrist whose middle joint's zero is bent: the xArm7's joint6, whose twin ended 163 degrees off
    unreported when only 0 and pi were tried)."""
    pos = robot.positions(robot.from_angles(a0[None]))[0]

    def misfit(d: np.ndarray) -> np.ndarray:
        b = _twin_angles(np.repeat(a0[None], len(d), 0), k, run, d, last_blind)
        pb = robot.positions(robot.from_angles(b))
        return np.linalg.norm(procrustes_align(pb, np.broadcast_to(pos, pb.shape)) - pos, axis=-1).max(1)

    grid = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    r = misfit(grid)
    out = []
    for d in grid[(r <= np.roll(r, 1)) & (r <= np.roll(r, -1))]:  # each local minimum, refined tenfold 4 times
        for step in np.radians([1.0, 0.1, 0.01, 0.001]):
            near = d + np.linspace(-step, step, 21)
            d = near[np.argmin(misfit(near))]
        exact = [e for e in (0.0, np.pi, -np.pi) if abs(d - e) < 1e-4]
        d = exact[0] if exact else d  # the textbook twins exactly
        if misfit(np.array([d]))[0] < tol and not any(abs(d - o) < 1e-4 for o in out):
            out.append(float(d))
    return out


def _near_twins(robot: RobotKinematics, q: np.ndarray, free: np.ndarray) -> list[np.ndarray]:
    """Motions (F, nq) that put the tracked points within :data:`NEAR_TWIN_SIZE` of the robot's size of
    where q (F, nq) puts them, by the pattern of :func:`_wrist_twins` with two or more middle joints (an
    arm over its shoulder: the first joint half a turn on, the parallel joints after it mirrored, the
    next half a turn on), as they are and with the first joint's turn left to the camera (``moved``).
    Starts for a refit, not alternatives: the offsets along the arm (a few centimetres)
    make them another motion, a little off the winner's points, whose refit the tracks judge.

    Why: the Kinova j2s6s200 (a 1 cm offset at its elbow) from below (full ranges, pinhole, 30 frames,
    seed 67) ended in that twin of the truth, joints 2-4 164, 132 and 178 degrees off and joint3 reported
    observable, 104 noise variances above the truth; the twin of the fit, 1.4-1.8 % of the robot's size
    off its points, refitted to the truth's basin, 178 noise variances below the fit."""
    out = []
    for run in range(2, robot.nv - 1):
        for moved in (False, True):
            out += _wrist_twins(robot, q, free, moved, run=run, tol=NEAR_TWIN_SIZE)
    return out


SHAKE_DEG = 20.0  # each observable joint's path shifted by this much either way: starts for other local minima
SHAKE_FAR_DEG = 60.0  # and by this much: basins beyond the near shift's reach
# and a turning joint by half a turn: the double pendulum's one moving point, nearly still (2.6 degrees
# over 30 frames, weak camera, full ranges, seed 33): a static triangle that a camera turned the other
# way sees alike with the joint 167 degrees away, tied (0.2 px^2 apart), and no shift above reached it
SHAKE_TURN_DEG = 180.0
SHAKE_RUNNERS_UP = 2  # the scored motions nearest the winner's score that are shaken too (basins two moves away)
# the shakes of a longer sequence run on every k-th frame, about this many, and only those that tie with
# the winner there are refitted on every frame: a basin is a whole path, which the sampled frames show,
# and a shake of 300 frames cost 5 of the UR10's 8 seconds
SHAKE_FRAMES = 30
SHAKE_REFITS = 4  # at most this many sampled shakes refitted on every frame (those that score lowest)


def _fit_objective(robot: RobotKinematics, qa: np.ndarray, rn: np.ndarray, w: np.ndarray, delta: float | None,
                   prior) -> float:
    """A fit's objective: robust residuals (norms rn (F, J), weights w, Huber threshold delta), plus the
    motion prior on its angles when there is one (None: squared residuals, as the unsmoothed fits)."""
    from .solver import _smoothed_objective

    if prior is None:
        return float((w * rn ** 2).sum())
    return _smoothed_objective(prior, robot.angles(qa), rn, w, delta)


def _sampled_prior(prior, F: int, nv: int, step: int, n: int):
    """The motion prior of every ``step``-th frame of F (n frames), for the search on them: the same joint
    accelerations cost the same per second (a second difference over ``step`` frames is step^2 times one
    over one frame: mu / step^4), or under the jerk prior the same jerks (mu / step^6). Read from the
    prior's matrix (the acceleration prior's frame 0 - frame 2 entry is mu alone, the jerk prior's frame
    0 - frame 3 entry -mu: nothing else couples frames that far apart); its terms beyond a joint's
    sightings are left out (the search only finds starts: its ties are refitted and scored with the full
    prior)."""
    from .solver import _jerk_prior, _motion_prior

    if prior is None:
        return None
    if prior_frames(prior, nv) == 3:  # the jerk prior: its frame 0 - frame 3 entry is -mu alone
        mu = -float(prior[0, 3 * nv])
        return _jerk_prior(np.zeros((n, nv), bool), mu / step ** 6, np.inf) if n > 3 else None
    mu = float(prior[0, 2 * nv]) if F >= 3 else 0.0
    return _motion_prior(np.zeros((n, nv), bool), mu / step ** 4, np.inf)


def _shake_fits(robot: RobotKinematics, q: np.ndarray, view, problem: "_Samples", shake: np.ndarray) -> list[tuple]:
    """Per joint in ``shake`` and shift (:data:`SHAKE_DEG`, :data:`SHAKE_FAR_DEG`, either way, and a
    turning joint by :data:`SHAKE_TURN_DEG`): q (F, nq) with that joint's path shifted, the camera
    re-fitted to it, then everything fitted again on ``problem``'s frames (:meth:`_Samples.fit`; q and
    view are for those frames). Returns the fits, (q, view, rn, ...) as the solvers do."""
    from .solver import _sequence_lm
    from .views import _camera_view, _View

    tracks, w, free = problem.tracks, problem.w, problem.free
    weak = isinstance(view, _View)
    ones = np.ones(view.n_params, bool)

    def shaken(k_shift):
        k, shift = k_shift
        dv = np.zeros((len(q), robot.nv))
        dv[:, k] = np.radians(shift)
        q0 = robot.integrate(q, dv * free, clip=True)
        if weak:
            v0 = _camera_view(robot.positions(q0), tracks, w, False)
        else:  # the pinhole camera alone, from the winner's, to the shifted motion
            v0 = _sequence_lm(robot, q0, tracks, w, view, np.zeros_like(free), ones, 30, 1e-10, problem.delta)[1]
        return problem.fit(q0, v0)

    shifts = [(k, shift) for k in np.flatnonzero(free.any(0) & shake) for shift in
              (SHAKE_DEG, -SHAKE_DEG, SHAKE_FAR_DEG, -SHAKE_FAR_DEG) + ((SHAKE_TURN_DEG,) if robot.turns_v[k] else ())]
    return map_tasks(robot, shaken, shifts)


def _sample_step(n_frames: int) -> int:
    """The stride that leaves about :data:`SHAKE_FRAMES` frames of a sequence for its searches (1: all)."""
    return -(-n_frames // SHAKE_FRAMES)


def _shaken(robot: RobotKinematics, base: dict, winner: dict, scored: list[tuple[float, dict]], tracks: np.ndarray,
            w: np.ndarray, prior, free: np.ndarray, shake: np.ndarray, var: float,
            settled: Callable[[dict], bool]) -> list[tuple[float, dict]]:
    """Other local minima near the winner, scored as ``scored`` is (:func:`_shake_fits`: per free joint,
    ``base``'s path shifted by :data:`SHAKE_DEG` and :data:`SHAKE_FAR_DEG` either way, a turning joint's
    also by :data:`SHAKE_TURN_DEG`, the camera re-fitted, everything fitted again). A minimum reached so
    that scores within the tie tolerance is a motion the tracks do not tell from the winner. ``shake``
    (nv,): the joints to shift (not those seen relative to frame 0, whose shift is a turn of the camera).
    ``base``: the winner, or any scored fit with ``out`` and ``delta`` (:func:`_runners_up`): its own
    shifts. ``var``: a noise variance in the objective's units. ``settled(fit)``: whether the camera-side
    rule sets a fit aside.

    A sequence longer than :data:`SHAKE_FRAMES` is shaken on every k-th frame (the motion prior made
    for them, :func:`_sampled_prior`), and only the shakes that tie with the winner there, and are new
    motions, are carried to every frame, refitted and scored (:func:`_sampled_shakes`; on the UR10's
    300 frames the search cost 2.6 s of a 12.8 s fit, most of it refitting shakes that had slid back to
    a motion scored already). Each carries where its camera looks from (``down``),
    so that the camera-side rule sets aside a shake that ended seen from the wrong side, as it sets
    aside the fit's own candidates (the milling arm, 300 frames: a shake ended on the mirror image seen
    from below, and its first joint, 34 degrees away, was reported ambiguous).

    Why: the fit's candidates are mirrors and flips of its own path; a shallow second basin, a few
    degrees to tens away with the camera moved with it, is none of those. TALOS's left arm (weak
    perspective, seed 0): the winner 8-14 degrees off on two shoulder joints with a reported std of
    0.4 degrees, and the true motion's basin 11 noise variances *lower*, reached from a shift of 20
    degrees of one joint; neither was in the fit's candidate set, so nothing was flagged."""
    from .views import _looks_down

    q, view, delta = base["out"][0], base["out"][1], base["delta"]
    if getattr(view, "per_frame", False):
        return []
    score = _scorer(robot, base, scored, tracks, w, prior)
    step = _sample_step(len(q))
    fits = (_shake_fits(robot, q, view, _Samples(robot, tracks, w, prior, free, 1, delta), shake) if step == 1 else
            _sampled_shakes(robot, base, winner, scored, tracks, w, prior, free, shake, var, step, settled))
    return [(score(r[0], r[2]), {"q": r[0], "down": _looks_down(r[1])}) for r in fits]


class _Samples:
    """Every ``step``-th frame of a sequence as a problem of its own, for the searches of a long one: the
    tracks, weights, free directions and acceleration prior (:func:`_sampled_prior`; step 1: the
    sequence itself, its own prior) of those frames,
    ``fit(q, view)`` (q, view for them; smoothed when there is a prior, the camera free) and
    ``objective(fit)``; ``bar(winner, var)``: the winner fitted there, plus the tie tolerance (``var`` a
    noise variance in the objective's units)."""

    def __init__(self, robot: RobotKinematics, tracks: np.ndarray, w: np.ndarray, prior, free: np.ndarray,
                 step: int, delta: float | None, n_iter: int = 50):
        F = len(tracks)
        self.robot, self.delta, self.n_iter = robot, delta, n_iter
        self.sub = np.arange(0, F, step)
        self.tracks, self.w, self.free = tracks[self.sub], w[self.sub], free[self.sub]
        self.prior = prior if step == 1 else _sampled_prior(prior, F, robot.nv, step, len(self.sub))

    def fit(self, q: np.ndarray, view) -> tuple:
        from .solver import _sequence_lm, _smooth_lm

        ones = np.ones(view.n_params, bool)
        if self.prior is None:
            return _sequence_lm(self.robot, q, self.tracks, self.w, view, self.free, ones, self.n_iter, 1e-8,
                                self.delta)
        return _smooth_lm(self.robot, self.robot.continuous(q), self.tracks, self.w, view, self.free, ones,
                          self.n_iter, 1e-8, self.delta, self.prior)

    def objective(self, fit: tuple) -> float:
        return _fit_objective(self.robot, fit[0], fit[2], self.w, self.delta, self.prior)

    def bar(self, winner: dict, var: float, variances: float | None = None) -> tuple[tuple, float]:
        """The winner fitted on these frames, and the highest objective that ties with it (within
        ``variances`` noise variances var; default the tie tolerance)."""
        from .candidates import TIE_VARIANCES

        reference = self.fit(winner["out"][0][self.sub], winner["out"][1].take(self.sub))
        return reference, self.objective(reference) + (TIE_VARIANCES if variances is None else variances) * var


def _tied_on_samples(robot: RobotKinematics, winner: dict, motions: list[np.ndarray], tracks: np.ndarray,
                     w: np.ndarray, prior, free: np.ndarray, var: float, step: int,
                     variances: float | None = None, new_only: bool = False) -> list[bool]:
    """Per motion of ``motions`` (each (F, nq)), whether, fitted on every ``step``-th frame from the winner's
    camera (:class:`_Samples`, 20 steps as the full refit), it ends within the tie tolerance (or
    ``variances`` noise variances var) of the winner fitted alike, and with ``new_only`` as another motion
    than that (:func:`chainspace.robot.candidates._same_motion`): the ones worth refitting on every frame
    (the depth flips of a 300-frame UR10 took about 0.6 s refitted in full)."""
    from .candidates import _same_motion

    samples = _Samples(robot, tracks, w, prior, free, step, winner["delta"], n_iter=20)
    reference, bar = samples.bar(winner, var, variances)
    view = winner["out"][1].take(samples.sub)
    fits = map_tasks(robot, lambda m: samples.fit(m[samples.sub], view), motions)
    return [samples.objective(f) <= bar and not (new_only and _same_motion(robot, f[0], reference[0])) for f in fits]


def _sampled_shakes(robot: RobotKinematics, base: dict, winner: dict, scored: list[tuple[float, dict]],
                    tracks: np.ndarray, w: np.ndarray, prior, free: np.ndarray, shake: np.ndarray, var: float,
                    step: int, settled: Callable[[dict], bool]) -> list[tuple]:
    """:func:`_shake_fits` of ``base``'s motion on every ``step``-th frame; those that end within the
    tie tolerance of the winner refitted there (objectives in units where ``var`` is a noise variance),
    that are no motion scored already and left standing (the winner, the fit's candidates that the
    camera-side rule, ``settled``, does not set aside) and distinct from each other (at
    most :data:`SHAKE_REFITS`, lowest first), carried to every frame (their change to the base motion
    interpolated between the sampled frames) and refitted there. Returns the refits, (q, view, rn, ...)
    as the solvers do."""
    from .candidates import _same_motion

    q, view = base["out"][0], base["out"][1]
    F = len(q)
    samples = _Samples(robot, tracks, w, prior, free, step, base["delta"])
    sub = samples.sub
    reference, bar = samples.bar(winner, var)
    # motions scored already and not set aside: refitting them again would add nothing (one set aside by
    # the camera side is refitted: on every frame it may end seen from the other side, a tie then)
    known = [reference[0]] + [x["q"][sub] for _, x in scored if "q" in x and len(x["q"]) == F and not settled(x)]

    def new(r) -> bool:
        return not any(_same_motion(robot, r[0], k) for k in known)

    tied: list[tuple[float, tuple]] = []
    for r in _shake_fits(robot, q[sub], view.take(sub), samples, shake):
        objective = samples.objective(r)
        if objective <= bar and new(r) and not any(_same_motion(robot, r[0], t[1][0]) for t in tied):
            tied.append((objective, r))
    full = _Samples(robot, tracks, w, prior, free, 1, base["delta"])  # every frame, the prior itself

    def carried(r):
        d = robot.wrap_angles(robot.angles(r[0]) - robot.angles(q[sub]))
        dv = np.stack([np.interp(np.arange(F), sub, d[:, k]) for k in range(robot.nv)], 1)
        # the one static camera of the sampled refit, for every frame
        return full.fit(robot.integrate(q, dv * free, clip=True), r[1].take(np.zeros(F, int)))

    return map_tasks(robot, carried, [r for _, r in sorted(tied, key=lambda t: t[0])[:SHAKE_REFITS]])


def _runners_up(robot: RobotKinematics, winner: dict, scored: list[tuple[float, dict]], n: int) -> list[dict]:
    """The ``n`` scored fits of lowest score after the winner, distinct motions from it and each other,
    among those with an ``out`` (q, view, rn, ...) and a ``delta``: the bases of :func:`_shaken` beyond
    the winner.

    Why: a basin can lie two moves from the winner, each move alone ending above the tie tolerance.
    TALOS's left arm through a weak camera from below (full ranges, 30 frames, seed 7): the true motion's
    basin 3.5 px^2 below the winner's (noise variance 0.7), reached by none of the fit's candidates; the
    static-line candidate had arm_left_2/3 right (25.9 noise variances above the winner), the winner
    shifted 60 degrees on arm_left_5 had that joint right (26.6 above). With the runners-up shaken too
    (and the far shift), the five joints 2-143 degrees off that were reported observable are flagged as
    a tie; the same for seed 3 (four joints 11-33 degrees off), which the far shift of the winner alone
    settles. On fresh seeds (12-17, above and below) the one silent run stayed silent."""
    from .candidates import _same_motion

    out: list[dict] = []
    for _, x in sorted(scored, key=lambda sx: sx[0]):
        if len(out) == n:
            break
        if x is winner or "out" not in x or "delta" not in x or \
                any(_same_motion(robot, x["out"][0], o["out"][0]) for o in [winner] + out):
            continue
        out.append(x)
    return out


DISTINCT_DEG = 2.0  # a frame's pose counts as the winner's when no joint differs by more (degrees; mm)


def _other_branch(robot: RobotKinematics, winner: dict, tracks: np.ndarray, w: np.ndarray, free: np.ndarray,
                  sigma: float, flips: list[np.ndarray], n_random: int = 12, seed: int = 1) -> list[dict]:
    """The best continuous motion that differs from the winner: per frame, the poses that fit that
    frame's tracks under the winner's camera (IK from random configurations, the winner's depth flips
    ``flips`` (:func:`chainspace.robot.candidates._depth_flips` of the winner's motion, camera and
    ``free``: the caller has them) and the rest-pose seeds, batched), those within :data:`DISTINCT_DEG`
    of the winner's pose left out (unless a frame has no other), then the path through them of the
    lowest cost by dynamic programming, as :func:`chainspace.robot.candidates._viterbi_branches` chooses a
    path (squared residuals over sigma^2, jumps between frames charged). Returns [{"q": (F, nq)}], or []
    when no such path exists.

    Why: the fit keeps one path and, of several that fit alike, the one nearest the rest pose; its
    candidates are local variants of the path it found (mirrors, flips of planar parts). A wrist whose
    only tracked point is seen along a ray can sit on another branch in every frame, a branch no mirror
    reaches (the xArm7's joint5 127 degrees off, as well fitted as the truth). This search looks for
    such a path directly, so that a tie is reported, not hidden."""
    from .kinematics import _held_q, _random_q, _seeded, _wrapped
    from .solver import _sequence_lm

    q, view, delta = winner["out"][0], winner["out"][1], winner["delta"]
    if getattr(view, "per_frame", False):
        return []
    F = len(q)
    held = _held_q(robot, free)
    rand = _random_q(robot, np.random.default_rng(seed), n_random)
    starts = [_seeded(robot, q, free), _seeded(robot, q, free, True)] + [np.where(held, q, r) for r in rand] + \
        [np.where(held, q, m) for m in flips]
    K = len(starts)
    idx = np.tile(np.arange(F), K)
    qs, _, rn, _, _, _ = _sequence_lm(robot, np.concatenate(starts), tracks[idx], w[idx], view.take(idx), free[idx],
                                      np.zeros(view.n_params, bool), 30, 1e-8, delta)
    qs = qs.reshape(K, F, -1)
    cost = (w[idx] * rn ** 2).sum(1).reshape(K, F) / max(sigma, 1e-12) ** 2
    diff = robot.wrap_angles(robot.angles(qs.reshape(K * F, -1)).reshape(K, F, -1) - robot.angles(q)[None])
    near = np.abs(diff).max(-1) < np.radians(DISTINCT_DEG)  # (K, F)
    if near.all():
        return []
    cost = np.where(near & ~near.all(0), np.inf, cost)  # the winner's own pose only where nothing else fits
    acc, back = cost[:, 0].copy(), np.zeros((F, K), int)
    for f in range(1, F):
        jump = np.linalg.norm(_wrapped(robot, qs[None, :, f] - qs[:, None, f - 1]), axis=-1)
        tot = acc[:, None] + (np.maximum(jump - 0.15, 0.0) / 0.1) ** 2
        back[f] = np.argmin(tot, 0)
        acc = tot[back[f], np.arange(K)] + cost[:, f]
    k = np.empty(F, int)
    k[-1] = int(np.argmin(acc))
    if not np.isfinite(acc[k[-1]]):
        return []
    for f in range(F - 1, 0, -1):
        k[f - 1] = back[f, k[f]]
    return [{"q": robot.continuous(qs[k, np.arange(F)])}]


def _tie_variances() -> float:
    from .candidates import TIE_VARIANCES

    return TIE_VARIANCES
