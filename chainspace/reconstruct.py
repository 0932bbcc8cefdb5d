"""Monocular reconstruction: 2D tracks of a kinematic chain -> 3D poses and weak-perspective cameras.

Methods
-------
``"kcs"``
    The paper's Algorithm 1 (:mod:`chainspace.kcs`): per-frame cameras and a nuclear-norm
    minimal deformation of the initial pose in the Kinematic Chain Space.
``"default"``
    ``"kcs"`` followed by the refinement of :mod:`chainspace.refine` (constant unknown bone lengths,
    temporal continuity, robust data term, the initial pose as a weak prior on depth signs).
``"rigid"``
    The Tomasi-Kanade rigid factorization with a metric upgrade, as a baseline: one shape for all
    frames, cameras per frame.

Units: the result is in the units and the scale of the initial pose (metres for shipped chains);
image quantities are in the units of the tracks (px).
"""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .camera import complete_rotation, fit_cameras
from .chain import KinematicChain
from .errors import ConvergenceWarning, TrackError
from .kcs import bone_observations, fit_translations, kcs_factorize, reprojection_rms
from .metrics import error_3d
from .refine import refine_bones

__all__ = ["reconstruct", "Reconstruction", "METHODS", "MIN_FRAMES", "MIN_POINTS"]

METHODS = ("default", "kcs", "rigid")
MIN_FRAMES = 2  # frames with at least MIN_POINTS visible points
MIN_POINTS = 3  # a weak-perspective camera needs two independent bones: three points


@dataclass
class Reconstruction:
    """Result of :func:`reconstruct` (in the manner of scipy's OptimizeResult).

    Attributes
    ----------
    poses : (F, J, 3) joint positions in the units of the initial pose, root at the origin.
    cameras : (F, 2, 3) weak-perspective cameras ``s_k R_k[:2]`` (image units per pose unit).
    translations : (F, 2) image translations: ``tracks ~= poses @ cameras^T + translations``.
    bone_lengths : (L,) link lengths (bones, then rigid links), mean over frames, pose units.
    tracks : (F, J, 2) the input tracks (NaN = not seen).
    confidence : (F, J) weights in [0, 1] used, or None when all points counted fully.
    chain : the kinematic chain.
    method : "default", "kcs" or "rigid".
    converged, n_iter, message : solver status (n_iter of the last stage).
    history : {stage: {quantity: [value per iteration]}}: "reprojection" (image units RMS),
        "error_3d" (pose units, only when the truth was given), "objective" (refine, px^2).
    timings : {stage: seconds}.
    """

    poses: np.ndarray
    cameras: np.ndarray
    translations: np.ndarray
    bone_lengths: np.ndarray
    tracks: np.ndarray
    confidence: np.ndarray | None
    chain: KinematicChain
    method: str
    converged: bool
    n_iter: int
    message: str
    history: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    def reprojection_error(self) -> float:
        """Confidence-weighted RMS distance (image units) between the tracks and the reprojection."""
        w = np.ones(self.tracks.shape[:2]) if self.confidence is None else self.confidence
        return reprojection_rms(self.tracks, w, self.poses, self.cameras, self.translations)

    def __repr__(self) -> str:
        F, J = self.poses.shape[:2]
        status = "converged" if self.converged else "NOT converged"
        total = sum(self.timings.values())
        return (
            f"Reconstruction({self.method!r}, {F} frames x {J} joints of {self.chain.name!r}, {status} "
            f"after {self.n_iter} iterations, reprojection {self.reprojection_error():.3g} px, "
            f"{total:.2f} s: {self.message})"
        )


# ---------------------------------------------------------------------------------------- validation
def _as_array(value: Any, what: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrackError(f"{what} are not numeric: {exc}") from None
    return arr


def _check_inputs(tracks, chain, init_pose, confidence, truth):
    if not isinstance(chain, KinematicChain):
        raise TrackError(f"chain must be a KinematicChain, not {type(chain).__name__}")
    W = _as_array(tracks, "tracks")
    if W.ndim == 3 and W.shape[-1] == 3 and confidence is None:
        W, confidence = W[..., :2], W[..., 2]  # a third channel is the confidence
    if W.ndim != 3 or W.shape[-1] != 2:
        raise TrackError(f"tracks have shape {W.shape}, expected (frames, joints, 2)")
    F, J = W.shape[:2]
    if J != chain.n_joints:
        raise TrackError(
            f"tracks have {J} joints but chain {chain.name!r} has {chain.n_joints} "
            f"({', '.join(chain.joints[:6])}, ...): map them with chain.reorder(tracks, names)"
        )
    bad = np.isinf(W)
    if bad.any():
        f, j, _ = np.argwhere(bad)[0]
        raise TrackError(f"tracks contain inf (first at frame {f}, joint {chain.joints[j]!r}); use NaN for unseen points")
    if confidence is None:
        c = np.ones((F, J))
        given = False
    else:
        c = _as_array(confidence, "confidences")
        if c.shape != (F, J):
            raise TrackError(f"confidence has shape {c.shape}, expected ({F}, {J}) like the tracks")
        if np.isinf(c).any() or (c[np.isfinite(c)] < 0).any() or (c[np.isfinite(c)] > 1).any():
            raise TrackError("confidences must be weights in [0, 1] (NaN counts as 0)")
        c = np.where(np.isfinite(c), c, 0.0)
        given = True
    seen = np.isfinite(W).all(-1) & (c > 0)
    never = np.flatnonzero(~seen.any(0))
    if len(never):
        names = ", ".join(repr(chain.joints[j]) for j in never[:5])
        raise TrackError(f"joint {names} is never seen (NaN or zero confidence in every frame); "
                         "drop it with chain.subset(...) or provide its track")
    usable = seen.sum(1) >= MIN_POINTS
    if F < MIN_FRAMES or usable.sum() < MIN_FRAMES:
        raise TrackError(
            f"a reconstruction needs at least {MIN_FRAMES} frames with at least {MIN_POINTS} visible "
            f"points each; got {F} frames, {int(usable.sum())} of them usable"
        )
    pts = W[seen]
    if np.ptp(pts, axis=0).max() <= 0:
        raise TrackError("tracks are constant: every visible point is at the same image position")
    W = np.where(seen[..., None], W, np.nan)
    c = np.where(seen, c, 0.0)
    if init_pose is None:
        if chain.rest_pose is None:
            raise TrackError(f"chain {chain.name!r} has no rest pose: pass init_pose (J, 3)")
        X0 = np.array(chain.rest_pose, dtype=float)
    else:
        X0 = _as_array(init_pose, "init_pose")
        if X0.shape != (J, 3) or not np.isfinite(X0).all():
            raise TrackError(f"init_pose must be a finite ({J}, 3) array, got shape {X0.shape}")
    lengths = chain.bone_lengths(X0)
    if (lengths <= 0).any():
        k = int(np.flatnonzero(lengths <= 0)[0])
        raise TrackError(f"init_pose gives link {chain.links[k]} zero length")
    T = None
    if truth is not None:
        T = _as_array(truth, "truth poses")
        if T.shape != (F, J, 3):
            raise TrackError(f"truth has shape {T.shape}, expected ({F}, {J}, 3)")
    return W, c, given, X0 - X0[chain.joint_index(chain.root)], T


# ---------------------------------------------------------------------------------------- methods
def _rigid(W, c, chain, X0):
    """Tomasi-Kanade: rank-3 factorization of the centred tracks, metric upgrade, scale from X0."""
    F, J = W.shape[:2]
    seen = c > 0
    Wf = np.where(seen[..., None], W, np.nan)
    mean = np.nanmean(Wf, axis=1, keepdims=True)
    Wc = np.where(seen[..., None], Wf - mean, 0.0)
    M2 = np.swapaxes(Wc, 1, 2).reshape(2 * F, J)
    for _ in range(20 if (~seen).any() else 1):  # impute missing entries with the rank-3 fit
        U, sv, Vt = np.linalg.svd(M2, full_matrices=False)
        fit = (U[:, :3] * sv[:3]) @ Vt[:3]
        M2 = np.where(np.repeat(seen, 2, axis=0).reshape(F, J, 2).transpose(0, 2, 1).reshape(2 * F, J), M2, fit) \
            if (~seen).any() else M2
    U, sv, Vt = np.linalg.svd(M2, full_matrices=False)
    M = (U[:, :3] * np.sqrt(sv[:3])).reshape(F, 2, 3)
    S = (np.sqrt(sv[:3])[:, None] * Vt[:3]).T  # (J, 3)
    # metric upgrade: symmetric G = Q Q^T with rows orthogonal and equal norms in every frame
    def sym_row(a, b):
        return np.stack([a[:, 0] * b[:, 0], a[:, 1] * b[:, 1], a[:, 2] * b[:, 2],
                         a[:, 0] * b[:, 1] + a[:, 1] * b[:, 0], a[:, 0] * b[:, 2] + a[:, 2] * b[:, 0],
                         a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1]], -1)
    m1, m2 = M[:, 0], M[:, 1]
    A = np.concatenate([sym_row(m1, m1) - sym_row(m2, m2), sym_row(m1, m2), sym_row(m1, m1)[:1]])
    b = np.zeros(len(A))
    b[-1] = 1.0
    g = np.linalg.lstsq(A, b, rcond=None)[0]
    G = np.array([[g[0], g[3], g[4]], [g[3], g[1], g[5]], [g[4], g[5], g[2]]])
    ev, V = np.linalg.eigh(G)
    Q = V * np.sqrt(np.maximum(ev, 1e-9 * max(ev.max(), 1e-300)))
    shape = S @ np.linalg.inv(Q).T  # (J, 3)
    # units and handedness from the initial pose (the factorization leaves scale and mirror free)
    shape = shape - shape[chain.joint_index(chain.root)]
    k = chain.bone_lengths(X0).sum() / max(chain.bone_lengths(shape).sum(), 1e-300)
    cands = [k * shape, k * shape * np.array([1.0, 1.0, -1.0])]
    from .metrics import procrustes_align
    errs = [np.linalg.norm(procrustes_align(s_, X0) - X0, axis=-1).mean() for s_ in cands]
    shape = cands[int(np.argmin(errs))]
    poses = np.broadcast_to(shape, (F, J, 3)).copy()
    Wb, wb = bone_observations(chain, W, c)
    P, s, R = fit_cameras(Wb, chain.bone_vectors(shape), wb, return_rotation=True)
    return poses, P


def _refine(W, c, chain, X0, kcs, T, max_iter, tol, options):
    nb = chain.n_bones
    Wb, wb = bone_observations(chain, W, c)
    R = kcs.rotations
    to_cam = lambda B: np.einsum("fij,flj->fli", R, B)  # noqa: E731 - world -> camera axes
    to_world = lambda x: np.einsum("fij,fli->flj", R, x)  # noqa: E731
    x0 = to_cam(chain.bone_vectors(kcs.poses)[:, :nb])
    prior = np.einsum("fij,lj->fli", R, chain.bone_vectors(X0)[:nb])
    hist: dict[str, list[float]] = {"reprojection": []}

    def monitor(x):
        X = chain.poses_from_bones(to_world(x))
        t = fit_translations(W, c, X, kcs.cameras)
        hist["reprojection"].append(reprojection_rms(W, c, X, kcs.cameras, t))
        if T is not None:
            hist.setdefault("error_3d", []).append(error_3d(X, T))

    res = refine_bones(Wb[:, :nb], wb[:, :nb], kcs.scales, prior, x0, max_iter=max_iter, tol=tol,
                       monitor=monitor, **options)
    hist.update(res.history)
    hist["start"] = res.start  # type: ignore[assignment]
    poses = chain.poses_from_bones(to_world(res.bones))
    return poses, res, hist


def reconstruct(
    tracks: Any,
    chain: KinematicChain,
    init_pose: Any = None,
    method: str = "default",
    *,
    confidence: Any = None,
    truth: Any = None,
    max_iter: int | None = None,
    tol: float | None = None,
    seed: Any = None,
    progress: bool = False,
    n_basis: int | None = None,
    refine_options: dict | None = None,
) -> Reconstruction:
    """3D poses and weak-perspective cameras of ``chain`` from 2D ``tracks`` of one camera.

    Parameters
    ----------
    tracks
        (F, J, 2) image positions in ``chain.joints`` order, NaN where a point is not seen; a third
        channel (F, J, 3) is read as the confidence.
    chain
        The kinematic chain; its rest pose is the default initial pose.
    init_pose
        (J, 3) initial pose; it sets the units and the scale of the result.
    method
        "default" (KCS + refinement), "kcs" (Algorithm 1 only) or "rigid" (Tomasi-Kanade baseline).
    confidence
        (F, J) weights in [0, 1] (0 or NaN = ignore the point).
    truth
        (F, J, 3) true poses, only for diagnostics: adds "error_3d" to the history.
    max_iter, tol
        Iteration limit and relative tolerance of each stage (defaults: KCS 10 / 1e-3,
        refinement 30 / 2e-3).
    seed
        Accepted for reproducibility; every method is deterministic.
    progress
        Print one line per stage to stderr.
    n_basis
        3K, the rank of the KCS pose basis (default min(J - 1, 15)).
    refine_options
        Weights of the refinement objective: lam_len, lam_smooth, lam_prior, delta (see
        :func:`chainspace.refine.refine_bones`).

    Raises
    ------
    TrackError
        Tracks, confidences or poses that cannot be used, with what is wrong and where. A
        reconstruction needs at least ``MIN_FRAMES`` frames with ``MIN_POINTS`` visible points.
    """
    if method not in METHODS:
        raise TrackError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    W, c, given, X0, T = _check_inputs(tracks, chain, init_pose, confidence, truth)
    del seed  # nothing is random; the argument keeps call sites explicit
    say = (lambda m: print(f"chainspace: {m}", file=sys.stderr)) if progress else (lambda m: None)  # noqa: E731
    timings: dict[str, float] = {}
    history: dict[str, dict[str, list[float]]] = {}
    t0 = time.perf_counter()
    if method == "rigid":
        say("rigid factorization")
        poses, P = _rigid(W, c, chain, X0)
        timings["rigid"] = time.perf_counter() - t0
        t = fit_translations(W, c, poses, P)
        history["rigid"] = {"reprojection": [reprojection_rms(W, c, poses, P, t)]}
        if T is not None:
            history["rigid"]["error_3d"] = [error_3d(poses, T)]
        return _result(W, c, given, chain, method, poses, P, t, True, 1, "rigid factorization", history, timings)

    say(f"KCS factorization of {W.shape[0]} frames")
    kcs = kcs_factorize(W, c, chain, X0, n_basis=n_basis, max_iter=max_iter or 10, tol=tol or 1e-3,
                        truth=T, error_fn=error_3d if T is not None else None)
    timings["kcs"] = time.perf_counter() - t0
    history["kcs"] = kcs.history
    poses, P, t = kcs.poses, kcs.cameras, kcs.translations
    converged, n_iter = kcs.converged, kcs.n_iter
    message = f"KCS {'converged' if kcs.converged else 'stopped at the iteration limit'} after {kcs.n_iter} iterations"
    if method == "default":
        say("refinement")
        t1 = time.perf_counter()
        poses, res, hist = _refine(W, c, chain, X0, kcs, T, max_iter or 30, tol or 2e-3, refine_options or {})
        timings["refine"] = time.perf_counter() - t1
        history["refine"] = hist
        t = fit_translations(W, c, poses, P)
        converged, n_iter = res.converged, res.n_iter
        message = (f"refinement {'converged' if res.converged else 'stopped at the iteration limit'} after "
                   f"{res.n_iter} iterations, started from the {res.start}")
    if not converged:
        warnings.warn(f"chainspace.reconstruct: {message}", ConvergenceWarning, stacklevel=2)
    return _result(W, c, given, chain, method, poses, P, t, converged, n_iter, message, history, timings)


def _result(W, c, given, chain, method, poses, P, t, converged, n_iter, message, history, timings):
    lengths = np.nanmean(chain.bone_lengths(poses), axis=0)
    return Reconstruction(poses, P, t, lengths, W, c if given else None, chain, method, bool(converged),
                          int(n_iter), message, history, timings)


class _CallableModule(type(sys)):
    """``chainspace.reconstruct`` is both this module and its main function: importing the module
    (``from chainspace.reconstruct import ...``) makes Python bind the package attribute
    ``chainspace.reconstruct`` to the module, so the module forwards calls to the function."""

    def __call__(self, *args: Any, **kwargs: Any) -> Reconstruction:
        return reconstruct(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
