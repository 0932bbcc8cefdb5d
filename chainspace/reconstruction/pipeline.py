"""Monocular reconstruction: 2D tracks of a kinematic chain -> 3D poses and weak-perspective cameras.

Methods
-------
``"kcs"``
    The paper's Algorithm 1 (:mod:`chainspace.reconstruction.kcs`): per-frame cameras and a nuclear-norm
    minimal deformation of the initial pose in the Kinematic Chain Space.
``"default"``
    ``"kcs"`` followed by the refinement of :mod:`chainspace.reconstruction.refine` (constant unknown bone lengths,
    temporal continuity, robust data term, the initial pose as a weak prior on depth signs).
``"rigid"``
    The Tomasi-Kanade rigid factorization with a metric upgrade, as a baseline: one shape for all
    frames, cameras per frame.

Units: the result is in the units and the scale of the initial pose (metres for shipped chains);
image quantities are in the units of the tracks (px).
"""

from __future__ import annotations

import contextlib
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cameras.weak import fit_cameras, smooth_scales
from ..chain import KinematicChain
from ..errors import CameraError, ChainspaceError, ConvergenceWarning, TrackError, is_real
from .kcs import (bone_observations, complex_points, fit_translations, kcs_factorize, reprojection_rms,
                  reprojection_with_translations, seen_points, where_seen)
from ..metrics import error_3d
from .refine import refine_bones

__all__ = ["reconstruct", "Reconstruction", "METHODS", "MIN_FRAMES", "MIN_POINTS", "track_score"]

METHODS = ("default", "kcs", "rigid")
MIN_FRAMES = 2  # frames with at least MIN_POINTS visible points
MIN_POINTS = 3  # a weak-perspective camera needs two independent bones: three points
UNDISTORT_TOL_PX = 1e-6  # a track point whose undistorted ray reprojects further away has no ray


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
        "error_3d" (pose units, only when the truth was given); for "refine" also "objective"
        (px^2, after every block) and its settings "noise" (estimated track noise, px), "delta"
        (Huber threshold, px) and "lam_smooth" (one value each).
    timings : {stage: seconds}.
    intrinsics : with a calibrated camera, its :class:`~chainspace.cameras.pinhole.PinholeCamera`;
        else None. Then ``poses`` are root-relative in the camera's axes (x right, y down, z along the view),
        ``cameras[k] = I[:2] / Z_k`` with ``Z_k`` the mean depth of the joints in frame k (pose
        units) and ``translations[k]`` the root's ray (x/z, y/z): ``tracks`` are reproduced by the
        perspective projection of ``points_camera``, ``poses @ cameras^T + translations`` is only
        its weak-perspective approximation in normalised image coordinates.
    points_camera : with intrinsics, (F, J, 3) the joints in camera axes (x right, y down, z along
        the view, pose units: the global scale is the initial pose's, as everywhere); the root
        depth of frame k is ``points_camera[k, root, 2]``. None without intrinsics.
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
    intrinsics: Any = None
    points_camera: np.ndarray | None = None

    def reprojection_error(self) -> float:
        """Confidence-weighted RMS distance (image units) between the tracks and the reprojection
        (with intrinsics: the perspective projection of ``points_camera``, pixels)."""
        w = np.ones(self.tracks.shape[:2]) if self.confidence is None else self.confidence
        if self.intrinsics is not None:
            return _rms(self.tracks, w, self.intrinsics.project(self.points_camera))
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


def _rms(tracks, weights, pred) -> float:
    seen = seen_points(tracks) & seen_points(pred)
    w = np.where(seen, weights, 0.0)
    d2 = np.where(seen, (where_seen(tracks - np.nan_to_num(pred), seen) ** 2).sum(-1), 0.0)
    return float(np.sqrt((w * d2).sum() / max(w.sum(), 1e-300)))


# ---------------------------------------------------------------------------------------- validation
def _as_array(value: Any, what: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrackError(f"{what} are not numeric: {exc}") from None
    return arr


def _never_seen(chain: KinematicChain, names: list[str], n_frames: int) -> str:
    """The error for joints with no visible point in any frame: every one named."""
    why = "(NaN or zero confidence in every frame)" if n_frames else "(the tracks have no frames)"
    if len(names) == chain.n_joints:
        return f"all {len(names)} joints of {chain.name} are never seen {why}: there is nothing to reconstruct"
    if len(names) == 1:
        return f"joint {names[0]!r} is never seen {why}; drop it with chain.subset(...) or provide its track"
    listed = ", ".join(map(repr, names[:-1])) + f" and {names[-1]!r}"
    return (f"{len(names)} joints, {listed}, are never seen {why}; drop them with chain.subset(...) or provide "
            "their tracks")


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
    seen = seen_points(W) & (c > 0)
    never = np.flatnonzero(~seen.any(0))
    if len(never):
        raise TrackError(_never_seen(chain, [chain.joints[j] for j in never], F))
    usable = seen.sum(1) >= MIN_POINTS
    if F < MIN_FRAMES or usable.sum() < MIN_FRAMES:
        raise TrackError(
            f"a reconstruction needs at least {MIN_FRAMES} frames with at least {MIN_POINTS} visible "
            f"points each; got {F} frames, {int(usable.sum())} of them usable"
        )
    ends = np.array([[chain.joint_index(a), chain.joint_index(b)] for a, b in chain.bones], int).reshape(-1, 2)
    two_bones = (seen[:, ends[:, 0]] & seen[:, ends[:, 1]]).sum(1) >= 2
    if two_bones.sum() < MIN_FRAMES:
        raise TrackError(
            f"a reconstruction needs at least {MIN_FRAMES} frames in which two whole bones are seen (both "
            f"ends of each; the camera is fitted to bones); got {int(two_bones.sum())}"
        )
    huge = np.abs(where_seen(W, seen)) > 1e12
    if huge.any():
        f, j, _ = np.argwhere(huge)[0]
        raise TrackError(f"tracks at frame {f}, joint {chain.joints[j]!r} reach {abs(W[f, j]).max():.3g}: "
                         "not an image coordinate (values beyond 1e12 cannot be used)")
    if max(np.ptp(W[..., k][seen]) for k in (0, 1)) <= 0:  # one coordinate at a time: fast
        raise TrackError("tracks are constant: every visible point is at the same image position")
    W = where_seen(W, seen, np.nan)
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


_REFINE_OPTIONS = ("lam_len", "lam_smooth", "lam_prior", "delta")


def _check_options(chain, max_iter, tol, n_basis, refine_options):
    def is_int(v):
        return isinstance(v, (int, np.integer)) and not isinstance(v, bool)

    def is_pos(v):
        return is_real(v) and v > 0

    if max_iter is not None and not (is_int(max_iter) and max_iter >= 1):
        raise TrackError(f"max_iter must be a whole number >= 1 (or None for the default), not {max_iter!r}")
    if tol is not None and not is_pos(tol):
        raise TrackError(f"tol must be a finite number > 0 (or None for the default), not {tol!r}")
    top = 3 * chain.n_bones
    if n_basis is not None and not (is_int(n_basis) and 1 <= n_basis <= top):
        raise TrackError(f"n_basis (3K, the rank of the KCS pose basis) must be a whole number in [1, {top}], "
                         f"not {n_basis!r}")
    if refine_options is not None:
        if not isinstance(refine_options, dict):
            raise TrackError(f"refine_options must be a dict, not {type(refine_options).__name__}")
        for k, v in refine_options.items():
            if k not in _REFINE_OPTIONS:
                raise TrackError(f"refine_options: unknown option {k!r}; known: {', '.join(_REFINE_OPTIONS)}")
            zero_ok = k in ("lam_len", "lam_smooth")
            if not (is_pos(v) or (zero_ok and is_real(v) and v == 0)):
                raise TrackError(f"refine_options: {k} must be a finite number {'>=' if zero_ok else '>'} 0, "
                                 f"not {v!r}")


# ---------------------------------------------------------------------------------------- methods
def _rigid(W, c, chain, X0):
    """Tomasi-Kanade: rank-3 factorization of the centred tracks, metric upgrade, scale from X0."""
    F, J = W.shape[:2]
    seen = c > 0
    M2 = np.swapaxes(where_seen(W, seen), 1, 2).reshape(2 * F, J)  # rows f0x, f0y, f1x, ...
    mask2 = np.repeat(seen, 2, axis=0)
    if not mask2.all():
        # Missing entries: each row is a rank-3 part (cameras times shape) plus the row's translation.
        # Impute: translation = mean of the completed row, rank-3 fit of the centred rows, refill,
        # until the imputed values settle (the right singular vectors from the J x J Gram matrix).
        rows = np.where(mask2, M2, 0.0).sum(1) / np.maximum(mask2.sum(1), 1)
        M2 = np.where(mask2, M2, rows[:, None])
        big = max(float(np.abs(M2).max()), 1e-300)
        for _ in range(5000):
            t = M2.mean(1, keepdims=True)
            Mc = M2 - t
            V = np.linalg.eigh(Mc.T @ Mc)[1][:, -3:]
            fit = (Mc @ V) @ V.T + t
            change = float(np.abs(fit - M2)[~mask2].max())
            M2 = np.where(mask2, M2, fit)
            if change <= 1e-12 * big:
                break
    M2 = M2 - M2.mean(1, keepdims=True)  # centre each row on the shape's centroid
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
    from ..metrics import procrustes_align
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
    to_cam = lambda B: B @ np.swapaxes(R, 1, 2)  # noqa: E731 - world -> camera axes
    to_world = lambda x: x @ R  # noqa: E731
    x0 = to_cam(chain.bone_vectors(kcs.poses)[:, :nb])
    prior = np.einsum("fij,lj->fli", R, chain.bone_vectors(X0)[:nb])
    hist: dict[str, list[float]] = {"reprojection": []}
    # Per-frame KCS scales jitter by a few percent; the camera distance changes slowly.
    scales = smooth_scales(kcs.scales, (wb > 0).sum(-1))
    cameras = scales[:, None, None] * R[:, :2]

    # the reprojection monitor runs frames last (see kcs.reprojection_with_translations)
    Dt = np.ascontiguousarray(chain.D.T)
    seen = seen_points(W)
    Wt = np.ascontiguousarray(where_seen(W, seen).transpose(2, 1, 0))  # (2, J, F)
    cw = np.ascontiguousarray(np.where(seen, c, 0.0).T)
    Pt = np.ascontiguousarray(cameras.transpose(1, 2, 0))

    def monitor(x):
        Xt = Dt @ np.ascontiguousarray(to_world(x).transpose(2, 1, 0))  # (3, J, F)
        hist["reprojection"].append(reprojection_with_translations(Wt, cw, Xt, Pt)[0])
        if T is not None:
            hist.setdefault("error_3d", []).append(error_3d(Xt.transpose(2, 1, 0), T))

    res = refine_bones(Wb[:, :nb], wb[:, :nb], scales, prior, x0, max_iter=max_iter, tol=tol,
                       parent_bone=_prior_parents(chain), monitor=monitor, **options)
    hist.update(res.history)
    poses = chain.poses_from_bones(to_world(res.bones))
    return poses, cameras, res, hist


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
    intrinsics: Any = None,
    perspective_iter: int = 1,
    blas_threads: int | None = 1,
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
        Accepted for reproducibility; every method is deterministic (nothing is drawn at random).
    progress
        Print one line per stage to stderr.
    n_basis
        3K, the rank of the KCS pose basis (default min(J - 1, 15)).
    refine_options
        Weights of the refinement objective: lam_len, lam_smooth, lam_prior, delta (see
        :func:`chainspace.reconstruction.refine.refine_bones`).
    intrinsics
        The calibrated camera that filmed the tracks, anything
        :func:`chainspace.cameras.pinhole.as_camera` takes: a
        :class:`~chainspace.cameras.pinhole.PinholeCamera` (OpenCV distortion), a (3, 3) matrix
        ``K`` (pixels) or a calibration file path. The tracks are undistorted to rays and the perspective is
        handled in three steps (:mod:`chainspace.reconstruction.perspective`): the rays are seen
        through virtual cameras turned towards the subject in every frame; the weak-perspective
        stages run on them, brought to one scale with the subject's depth in every frame estimated
        from the image bone lengths (a first weak pass gives the lengths); a perspective refinement (per frame: root position and bones in camera
        axes; shared bone lengths) fits the full pinhole model. ``perspective_iter`` > 1 adds
        POSIT-style passes that rerun the weak-perspective stages on rays corrected with the
        previous pass's depths; default 1 (no such pass): on CMU 35_01/35_02 (straight, turning,
        towards/away, 0 and 2 px) one pass gave 28.6-48.0 mm (mean 37.5), two passes 21.4-73.0 mm
        (mean 40.8): they help noise-free walks (turning 40.1 -> 32.6 and 35.8 -> 27.4 mm) and
        hurt turning walks with 2 px noise (42.2 -> 58.5 and 40.3 -> 73.0 mm). See
        ``Reconstruction.intrinsics`` for what cameras and translations mean then.
    blas_threads
        BLAS threads while it runs (see Notes): 1 by default, ``None`` to leave the BLAS
        library's own setting (usually all cores).

    Raises
    ------
    TrackError
        Tracks, confidences or poses that cannot be used, with what is wrong and where. A
        reconstruction needs at least ``MIN_FRAMES`` frames with ``MIN_POINTS`` visible points.
    CameraError
        ``intrinsics`` that cannot be used (see :func:`~chainspace.cameras.pinhole.as_camera`), or a
        lens distortion that cannot be undone for most of the tracked points.

    Notes
    -----
    While it runs, BLAS is limited to ``blas_threads`` threads (one) through ``threadpoolctl``
    (the previous limits are restored on return; nothing is set in the environment). The matrix
    products here are thin (frames x 15): BLAS threads add little, and on a busy machine they
    made the KCS stage 3-4 times slower (``benchmarks/bench_speed.py`` measures both).
    """
    if method not in METHODS:
        raise TrackError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if not isinstance(chain, KinematicChain):
        raise TrackError(f"chain must be a KinematicChain, not {type(chain).__name__} "
                         "(load one with chainspace.load_chain or chainspace.shipped)")
    _check_options(chain, max_iter, tol, n_basis, refine_options)
    if not (_whole(perspective_iter) and perspective_iter >= 1):
        raise TrackError(f"perspective_iter must be a whole number >= 1, not {perspective_iter!r}")
    if blas_threads is not None and not (_whole(blas_threads) and blas_threads >= 1):
        raise TrackError(f"blas_threads must be a whole number >= 1 or None, not {blas_threads!r}")
    camera = None
    if intrinsics is not None:
        from ..cameras.pinhole import as_camera
        camera = as_camera(intrinsics)
    W, c, given, X0, T = _check_inputs(tracks, chain, init_pose, confidence, truth)
    try:
        with np.errstate(all="ignore"), _one_blas_thread(blas_threads):
            if camera is not None:
                return _run_perspective(W, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis,
                                        refine_options, camera, int(perspective_iter))
            return _run(W, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, refine_options)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        if isinstance(exc, ChainspaceError):  # TrackError, CameraError: already say what is wrong
            raise
        raise TrackError(f"the reconstruction failed numerically on these tracks ({type(exc).__name__}: {exc}); "
                         "check for degenerate tracks (points that never move apart)") from None


def _whole(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


_BLAS: list = []  # the threadpoolctl controller, made on first use (finding the libraries takes ~15 ms)


def _one_blas_thread(n: int | None = 1):
    """A context limiting BLAS to n threads (threadpoolctl), or doing nothing when n is None or
    without threadpoolctl."""
    if not _BLAS:
        try:
            from threadpoolctl import ThreadpoolController
            _BLAS.append(ThreadpoolController())
        except Exception:  # not installed, or no BLAS found: run with the defaults
            _BLAS.append(None)
    if _BLAS[0] is None or n is None:
        return contextlib.nullcontext()
    return _BLAS[0].limit(limits=int(n), user_api="blas")


def _run(W_in, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, refine_options):
    """The stages of :func:`reconstruct` on validated inputs, in normalised image units (tracks
    centred and divided by their typical spread, so any unit from 1e-6 to 1e12 behaves the same);
    cameras, translations and image-unit histories are mapped back at the end."""
    seen = c > 0
    z = complex_points(W_in, seen).sum() / seen.sum()
    center = np.array([z.real, z.imag])
    unit = _spread(W_in, seen)
    W = (W_in - center) / unit
    options = dict(refine_options or {})
    if "delta" in options:  # the Huber threshold is given in image units
        options["delta"] = options["delta"] / unit
    rec = _stages(W, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, options)
    rec.tracks = W_in
    rec.cameras = rec.cameras * unit
    rec.translations = rec.translations * unit + center
    for stage in rec.history.values():
        if "reprojection" in stage:
            stage["reprojection"] = [v * unit for v in stage["reprojection"]]
        for key in ("delta", "noise"):  # refinement settings in image units
            if key in stage:
                stage[key] = [v * unit for v in stage[key]]
        if "objective" in stage:
            stage["objective"] = [v * unit**2 for v in stage["objective"]]
    return rec


def _run_perspective(W_px, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, refine_options,
                     camera, n_pass):
    """:func:`_run` on the camera's rays, corrected for perspective pass after pass (see
    :mod:`chainspace.reconstruction.perspective`)."""
    from ..cameras.pose import pose_from_weak
    from .perspective import centring_rotations, depth_from_bones, perspective_refine, turn_rays

    rays = camera.rays(W_px)
    # a ray whose distortion does not land back on its pixel has no undistorted position (past the
    # fold of the distortion polynomial, where the model is not one-to-one)
    with np.errstate(all="ignore"):
        miss = np.linalg.norm(camera.distort(rays) - W_px, axis=-1)
    seen = seen_points(W_px)
    bad = seen & ~(miss < UNDISTORT_TOL_PX)
    rays[bad] = np.nan
    if bad.sum() > 0.5 * seen.sum():
        raise CameraError(f"intrinsics: the lens distortion cannot be undone for {bad.sum() / seen.sum():.0%} of "
                          "the tracked points (the distortion model is not one-to-one there): check dist and K")
    c = np.where(np.isfinite(rays).all(-1), c, 0.0)
    if ((c > 0).sum(1) >= MIN_POINTS).sum() < MIN_FRAMES:
        raise CameraError("intrinsics: after undistortion too few points are left to reconstruct")
    rays = np.where((c > 0)[..., None], rays, np.nan)
    opts = dict(refine_options or {})
    if "delta" in opts:  # given in pixels: rays are pixels / f
        opts["delta"] = opts["delta"] / float(np.sqrt(camera.fx * camera.fy))
    # virtual cameras turned towards the subject in every frame: there weak perspective is accurate
    Q = centring_rotations(rays, c)
    rays = turn_rays(rays, Q)
    persp: dict[str, list[float]] = {"reprojection": [], "change": []}
    timings: dict[str, float] = {}
    Wc, rec = rays, None
    # one image scale for the weak stages: the subject's distance changes over a sequence (a walk
    # round a circle 3-5 m away: +-10-15 %), which they cope with badly. A first weak pass gives the
    # bone lengths; the depth of every frame follows from its image bone lengths (smoothed in time);
    # frame k's rays times depth_k / mean depth are then seen at one common scale.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        rec0 = _run(rays, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, opts)
    for k, v in rec0.timings.items():
        timings["depth " + k] = v
    depth = depth_from_bones(chain, rays, np.nanmean(chain.bone_lengths(rec0.poses), axis=0))
    gain = depth / depth.mean()  # rays of frame k are multiplied by gain[k] before the weak stages
    Wc = rays * gain[:, None, None]
    for i in range(n_pass):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            rec = _run(Wc, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, opts)
        for k, v in rec.timings.items():
            timings[k] = timings.get(k, 0.0) + v
        rec.cameras = rec.cameras / gain[:, None, None]  # back to the real rays' scales
        rec.translations = rec.translations / gain[:, None]
        # the weak cameras on rays placed as pinhole poses about the frame's weighted centroid, whose
        # depth is 1 / scale: d is each joint's depth relative to it
        centre = np.einsum("fj,fjc->fc", c, rec.poses) / np.maximum(c.sum(1), 1e-300)[:, None]
        R, t = pose_from_weak(rec.cameras, rec.translations, None, centre)
        pts = np.einsum("fij,fkj->fki", R, rec.poses) + t[:, None]
        scale = np.sqrt((rec.cameras**2).sum(-1)).mean(-1)
        d = pts[..., 2] - 1.0 / scale[:, None]
        pts = pts @ Q  # virtual camera axes -> the real camera's
        persp["reprojection"].append(_rms(W_px, c, camera.project(pts)))
        # at the common scale of the first pass: without the gain the next pass would see the
        # subject's distance change again (the error the common scale is there to remove)
        corrected = rays * ((1.0 + scale[:, None] * d) * gain[:, None])[..., None]
        seen = c > 0
        size = _spread(rays, seen)
        change = float(np.abs(where_seen(corrected - Wc, seen)).max()) / size
        persp["change"].append(change)
        if progress:
            print(f"chainspace: perspective pass {i + 1}: reprojection {persp['reprojection'][-1]:.3g} px, "
                  f"rays moved {change:.2g} of the subject's size", file=sys.stderr)
        if change < 1e-3 or i == n_pass - 1:
            break
        Wc = corrected
    # the full perspective model, from the corrected weak-perspective result (virtual camera axes)
    t1 = time.perf_counter()
    pts_v = pts @ np.swapaxes(Q, 1, 2)
    nb = chain.n_bones
    r_idx = chain.joint_index(chain.root)
    xb, Tr, lengths, ph = perspective_refine(rays, c, chain.D, chain.bone_vectors(pts_v)[:, :nb], pts_v[:, r_idx])
    timings["perspective"] = time.perf_counter() - t1
    persp["cost"] = ph["cost"]
    xb = xb @ Q  # bones in the real camera's axes
    Tr = np.einsum("fij,fi->fj", Q, Tr)
    poses = chain.poses_from_bones(xb)
    pts = poses + Tr[:, None]
    persp["reprojection"].append(_rms(W_px, c, camera.project(pts)))
    if T is not None:
        persp["error_3d"] = [error_3d(poses, T)]
    rec.poses = poses
    rec.bone_lengths = np.nanmean(chain.bone_lengths(poses), axis=0)
    rec.tracks = W_px
    # poses are in camera axes: cameras I[:2] / Z_k (Z_k the mean depth of the joints), translations
    # the root's ray
    Zk = pts[..., 2].mean(1)
    rec.cameras = np.broadcast_to(np.eye(3)[:2], (len(pts), 2, 3)) / Zk[:, None, None]
    rec.translations = Tr[:, :2] / Zk[:, None]
    rec.intrinsics = camera
    rec.points_camera = pts
    rec.history["perspective"] = persp
    rec.timings = timings
    rec.message += (f"; perspective: {len(persp['change'])} pass(es), reprojection "
                    f"{persp['reprojection'][-1]:.3g} px")
    if not rec.converged:
        warnings.warn(f"chainspace.reconstruct: {rec.message}", ConvergenceWarning, stacklevel=3)
    return rec


def _real_cameras(P, Q):
    """Weak-perspective cameras s R_v[:2] of the virtual cameras Q (F, 3, 3) -> s (Q^T R_v)[:2]."""
    s = np.sqrt((P**2).sum(-1)).mean(-1)
    r1, r2 = P[:, 0] / s[:, None], P[:, 1] / s[:, None]
    Rv = np.stack([r1, r2, np.cross(r1, r2)], 1)
    return s[:, None, None] * (np.swapaxes(Q, 1, 2) @ Rv)[:, :2]


def _spread(W, seen):
    """Typical distance of a frame's visible points from their centroid (median over frames)."""
    n = np.maximum(seen.sum(1), 1)
    z = complex_points(W, seen)
    m = z.sum(1) / n
    dz = np.where(seen, z - m[:, None], 0.0)
    d = np.sqrt((dz.real**2 + dz.imag**2).sum(1) / n)
    d = d[(seen.sum(1) >= 2) & (d > 0)]
    unit = float(np.median(d)) if len(d) else float(np.ptp(W[seen], axis=0).max())
    return unit if unit > 0 else 1.0


def _stages(W, c, given, X0, T, chain, method, max_iter, tol, progress, n_basis, refine_options):
    """The stages of :func:`reconstruct`."""
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
    kcs = kcs_factorize(W, c, chain, X0, n_basis=n_basis, max_iter=max_iter if max_iter is not None else 10,
                        tol=tol if tol is not None else 1e-3,
                        truth=T, error_fn=error_3d if T is not None else None)
    timings["kcs"] = time.perf_counter() - t0
    history["kcs"] = kcs.history
    poses, P, t = kcs.poses, kcs.cameras, kcs.translations
    converged, n_iter = kcs.converged, kcs.n_iter
    message = f"KCS {'converged' if kcs.converged else 'stopped at the iteration limit'} after {kcs.n_iter} iterations"
    if method == "default":
        say("refinement")
        t1 = time.perf_counter()
        poses, P, res, hist = _refine(W, c, chain, X0, kcs, T, max_iter if max_iter is not None else 30,
                                          tol if tol is not None else 2e-3, refine_options or {})
        timings["refine"] = time.perf_counter() - t1
        history["refine"] = hist
        t = fit_translations(W, c, poses, P)
        converged, n_iter = res.converged, res.n_iter
        message = (f"refinement {'converged' if res.converged else 'stopped at the iteration limit'} after "
                   f"{res.n_iter} iterations, started from the {res.start}")
        # Keep the refinement only if the tracks say it is better: the track score (normalised
        # reprojection + bone-length variation) of each stage, never the truth.
        size = _spread(W, c > 0)
        sk = track_score(W, c, chain, kcs.poses, kcs.cameras, kcs.translations, spread=size)
        sr = track_score(W, c, chain, poses, P, t, spread=size)
        history["selection"] = {"kcs": list(sk), "refine": list(sr)}
        if sk[0] < sr[0]:
            poses, P, t = kcs.poses, kcs.cameras, kcs.translations
            message += (f"; kept the KCS stage: its track score {sk[0]:.4g} is below the refinement's {sr[0]:.4g} "
                        "(normalised reprojection + bone-length variation)")
            history["selection"]["chosen"] = ["kcs"]
        else:
            message += f"; track score {sr[0]:.4g} (KCS stage {sk[0]:.4g})"
            history["selection"]["chosen"] = ["refine"]
    if not converged:
        warnings.warn(f"chainspace.reconstruct: {message}", ConvergenceWarning, stacklevel=4)
    return _result(W, c, given, chain, method, poses, P, t, converged, n_iter, message, history, timings)


def _result(W, c, given, chain, method, poses, P, t, converged, n_iter, message, history, timings):
    lengths = np.nanmean(chain.bone_lengths(poses), axis=0)
    return Reconstruction(poses, P, t, lengths, W, c if given else None, chain, method, bool(converged),
                          int(n_iter), message, history, timings)


def track_score(W, c, chain, poses, P, t, *, spread: float | None = None) -> tuple[float, float, float]:
    """What the tracks say about a reconstruction, lower is better: ``(score, rms, variation)``
    with ``rms`` the weighted reprojection RMS under the stage's own weak-perspective cameras
    divided by the subject's size in the image (:func:`_spread`: the median distance of the
    points from their centroid) and ``variation`` the bone-length variation across frames (summed
    standard deviations over summed mean lengths of the bones). ``score = rms + variation``.
    ``spread``: that size if already known (two stages scored on the same tracks)."""
    rms = reprojection_rms(W, c, poses, P, t) / (_spread(W, c > 0) if spread is None else spread)
    lengths = chain.bone_lengths(poses)[:, :chain.n_bones]
    var = float(np.nanstd(lengths, axis=0).sum() / max(np.nanmean(lengths, axis=0).sum(), 1e-300))
    return float(rms + var), float(rms), var


def _prior_parents(chain: KinematicChain) -> np.ndarray:
    """(n_bones,) for each bone the bone before it when its parent joint has exactly one child (a
    knee, an elbow: the prior keeps the bend relative to that bone), else -1 (a branching joint such
    as the pelvis or the thorax: the prior is the initial pose's bone in camera axes)."""
    child_of = {b: k for k, (_, b) in enumerate(chain.bones)}
    n_children: dict[str, int] = {}
    for a, _ in chain.bones:
        n_children[a] = n_children.get(a, 0) + 1
    return np.array([child_of.get(a, -1) if n_children[a] == 1 else -1 for a, _ in chain.bones])
