"""Calibrated cameras: pixel tracks -> the camera's rays, and the perspective stages of
:func:`chainspace.reconstruction.pipeline.reconstruct` with ``intrinsics``.

The camera is the project's one model, :class:`chainspace.cameras.pinhole.PinholeCamera`: it turns
pixels into rays (:meth:`~chainspace.cameras.pinhole.PinholeCamera.rays`, distortion removed) and
points back into pixels (:meth:`~chainspace.cameras.pinhole.PinholeCamera.project`).

Steps: (1) undistort and normalise the tracks to rays; (2) turn the camera about its centre in
every frame so that the subject's mean ray is the optical axis (:func:`centring_rotations`; weak
perspective is most accurate for a centred subject); (3) the weak-perspective stages on those rays
brought to one scale: a first weak pass gives the bone lengths, :func:`depth_from_bones` the depth
of the subject in every frame, and frame k's rays are multiplied by its depth / the mean depth;
optionally (``perspective_iter`` > 1) more passes on rays corrected as below; (4)
:func:`perspective_refine`: the full pinhole model, per frame the root position and the bones in
camera axes, bone lengths shared by all frames, from the weak-perspective result.

The correction passes (off by default, see ``reconstruct``). A weak-perspective camera on rays has the
scale ``s_k = 1 / Z_k`` (the inverse depth of the subject's centroid in frame k, per pose unit); under
perspective a joint at depth ``Z_kj = Z_k + d_kj`` (``d_kj`` its depth relative to the centroid in
camera axes) is seen at ``ray_kj = C_kj[:2] / Z_kj``, while the scaled orthographic view of the same
point is ``C_kj[:2] / Z_k = ray_kj (1 + s_k d_kj)``. The correction (in the manner of POSIT, DeMenthon
and Davis 1995) alternates: reconstruct with the weak-perspective pipeline from the corrected rays (at
the common scale of step 3), then correct the rays with the depths of that reconstruction. At a fixed
point with the right depths the corrected rays are exactly a scaled orthographic view of the motion, so
the weak-perspective stages see what they see in an orthographic view of the same motion: with the true
depths, CMU 35_01 (straight, turning, towards/away; 0 and 2 px) came out at 16.0-49.6 mm, the
orthographic view's 17.9-46.6 mm. In practice one pass's depths remove about half of the perspective
(RMS of the factor's error 0.021 against the perspective's 0.037, turning walk at 2 px) and the passes
do not settle: the refinement's start (the KCS bones lifted onto the data with Viterbi signs) changes
basin with small changes of the rays (that walk: 38, 63, 46, 60 mm in passes 1-4, while the KCS stage
stays at 46-47 mm), so passes help noise-free walks and hurt noisy turning ones (see ``reconstruct``).
Correcting the tracks inside the refinement from its own bones, every sweep, drifted further (35_01
straight, 0 px: 38 -> 74 mm after the weak stages): a bone near the image plane turns a small change of
its image length into a large change of its depth, so such an alternation is unstable there; the depths
and the image have to be solved together, as :func:`perspective_refine` does per frame. Tried that way
on 2026-12-06 and not kept (local branch ``experiment/perspective-refine``): the refinement with the
perspective data term (given its parent's depth a bone's residual is linear in the bone, ``s x[:2] -
kappa W_child x[2] - (W_child - W_parent)(1 + kappa d_parent)``, exact at the truth) in its Gauss-Newton
step and the two ray-sphere intersections as its sign proposals. On CMU 35_01/35_02 (tune set, 12 runs)
it ended at 37.1 mm at 0 px (36.7 without it) and 43.2 mm at 2 px (38.3). Started from the truth it
stays there (3.7 mm, true cameras and a prior turned to the truth); started 5 cm off (per bone
coordinate) it ends 51 mm off, as the weak refinement on an orthographic view does from such starts (41
mm): the refinement's basin is narrow and its start decides. The weak-perspective stages also suffer
from the scale 1 / Z_k changing over a sequence (a subject walking a circle 3.5-4.7 m away: exactly
corrected rays at the per-frame scales 50.8 mm, rescaled to one scale 22.2 mm), hence step (3)'s common
scale. Depths from the weak stage's own per-frame camera scales were too rough for it (1-6.5 % off, no
gain); from the image bone lengths (:func:`depth_from_bones`, 0.3-1 % off) the static-camera benchmark's
tune set (CMU 35_01, 35_02; straight, turning, towards/away; 0 and 2 px) went from 45.5 to 37.5 mm on
average (turning at 2 px 66.9 -> 41.2 mm), the same as with the true depths (37.5 mm).

Tried and not kept (2026-12-02, CMU 35_01): a bundle adjustment of the whole sequence on the real
camera's rays (per-frame root and bones, shared lengths, Huber data term, second differences in
time, a banded Gauss-Newton) started from the weak result. It lowered its objective but raised the
3D error (straight walk, 0 px: 38.0 -> 51.6 mm; from the KCS stage 35.3 -> 46.9 mm), while the
true motion's objective is ten times lower (0.0015 against 0.017): the objective is right, the start
is in the wrong basin (ankles and wrists, i.e. depth choices). A POSIT pass (rays corrected with
a reconstruction's depths, the weak stages rerun) then the adjustment gave 24.2 mm on that walk
(16.0 with the true depths), but on the turning walk at 2 px 43.3 -> 56.5 mm. A depth-choice
search under perspective (as refine.py's Viterbi over signs) is what is missing, not a better
local solver.
"""

from __future__ import annotations

from typing import Any

import numpy as np


__all__ = ["centring_rotations", "turn_rays", "depth_from_bones", "perspective_refine"]


def centring_rotations(rays: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations Q_k of virtual cameras that turn the camera about its centre so that the
    subject's mean ray in frame k lies on the optical axis (``Q_k v_k = e_z``, the smallest such
    rotation). Seen through them the subject is centred, where weak perspective is most accurate
    (the error of the scaled orthographic model grows with the distance from the image centre)."""
    seen = np.isfinite(rays).all(-1)
    w = np.where(seen, weights, 0.0)
    m = (w[..., None] * np.where(seen[..., None], rays, 0.0)).sum(1) / np.maximum(w.sum(1), 1e-300)[:, None]
    v = np.concatenate([m, np.ones((len(m), 1))], -1)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    ez = np.array([0.0, 0.0, 1.0])
    a = np.cross(v, ez)  # axis * sin
    c = v @ ez
    ax = np.zeros((len(v), 3, 3))
    ax[:, 0, 1], ax[:, 0, 2], ax[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
    ax = ax - np.swapaxes(ax, 1, 2)
    return np.eye(3) + ax + (ax @ ax) / (1.0 + c)[:, None, None]


def turn_rays(rays: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Rays (F, J, 2) (x/z, y/z) seen by cameras turned by Q (F, 3, 3)."""
    h = np.concatenate([rays, np.ones(rays.shape[:-1] + (1,))], -1) @ np.swapaxes(Q, 1, 2)
    return h[..., :2] / h[..., 2:]


def depth_from_bones(chain: Any, rays: np.ndarray, lengths: np.ndarray, *, quantile: float = 0.75,
                     median_frames: int = 9, sigma_frames: float = 15.0) -> np.ndarray:
    """(F,) depth of the subject in every frame (pose units, up to the global scale of ``lengths``)
    from its image bone lengths: a bone of length ``l_b`` at depth ``Z_k`` spans at most ``l_b / Z_k``
    in rays, the full length when it lies in the image plane. Per frame ``1 / Z_k`` is the
    ``quantile`` over the seen bones of ``|ray bone| / l_b`` (the upper quantile: the bones most
    nearly parallel to the image plane, robust to a few wrong ones), then smoothed over time (a
    running median of ``median_frames``, then a Gaussian of ``sigma_frames``); frames without a
    seen bone are interpolated. On CMU 35_01/35_02 filmed 3-5 m away (distance changing by 7-15 %
    over a sequence) its relative error was 0.3-1.0 %, against 1-6.5 % for the weak stage's
    per-frame camera scales (whose foreshortening trades with the depth of the reconstructed bones).
    """
    from scipy.ndimage import gaussian_filter1d, median_filter

    nb = chain.n_bones
    r = np.concatenate([rays, np.zeros(rays.shape[:2] + (1,))], -1)
    image = np.linalg.norm(chain.bone_vectors(r)[:, :nb, :2], axis=-1)  # NaN where an end is not seen
    lb = np.asarray(lengths, float)[:nb]
    ratio = np.where(lb > 0, image / np.where(lb > 0, lb, 1.0), np.nan)
    ok = np.isfinite(ratio).any(1)
    if not ok.any():
        return np.ones(len(rays))
    with np.errstate(all="ignore"):
        inv = np.full(len(rays), np.nan)
        inv[ok] = np.nanquantile(ratio[ok], quantile, axis=1)
    good = ok & (inv > 0) & np.isfinite(inv)
    if not good.any():
        return np.ones(len(rays))
    t = np.arange(len(rays))
    z = np.interp(t, t[good], 1.0 / inv[good])
    z = median_filter(z, size=min(median_frames, len(z)), mode="nearest")
    return gaussian_filter1d(z, sigma_frames, mode="nearest")


def perspective_refine(rays: np.ndarray, weights: np.ndarray, D: np.ndarray, bones: np.ndarray, root: np.ndarray,
                       *, lam_len: float = 10.0, lam_prior: float = 0.3, n_outer: int = 2, n_iter: int = 10
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, list[float]]]:
    """Fit the full perspective model to rays, frame by frame with shared bone lengths.

    Unknowns per frame k: the root position ``T_k`` (3,) in camera axes and the bones ``x_kb``
    (n_bones, 3); joints ``C_kj = T_k + sum_b D[b, j] x_kb``. Per frame it minimises (residuals in
    pose units at the subject's distance: ray errors times the depth ``Z_k``)

        sum_j w_kj Z_k^2 |C_kj[:2] / C_kj[2] - ray_kj|^2 + lam_len sum_b (|x_kb| - l_b)^2
        + lam_prior sum_b |x_kb - x0_kb|^2

    by Levenberg-Marquardt vectorised over frames (a frame's step is taken only if its cost
    drops), ``n_iter`` steps; then the lengths ``l_b = mean_k |x_kb|`` (their exact minimiser),
    ``n_outer`` times. ``x0`` is the start (the weak-perspective result in camera axes): the weak
    prior keeps the depth-sign choices of the start where the images cannot tell. Returns
    ``(bones, root, lengths, history)``.
    """
    F, J = rays.shape[:2]
    nb = bones.shape[1]
    seen = np.isfinite(rays).all(-1)
    w = np.where(seen, weights, 0.0)
    v = np.where(seen[..., None], rays, 0.0)
    x0 = bones.copy()
    x, T = bones.copy(), root.copy()
    l = np.linalg.norm(x, axis=-1).mean(0)
    Dt = np.asarray(D, float)[:nb]  # (nb, J)
    n = 3 + 3 * nb
    hist: dict[str, list[float]] = {"cost": []}

    def residuals(x, T, l):
        C = T[:, None] + np.einsum("fbc,bj->fjc", x, Dt)
        z = C[..., 2]
        Z = np.abs(C[..., 2]).mean(1)  # ~ the subject's depth
        zs = np.where(np.abs(z) > 1e-9, z, 1e-9)
        p = C[..., :2] / zs[..., None]
        sw = np.sqrt(w)[..., None] * Z[:, None, None]
        r_data = (sw * (p - v)).reshape(F, -1)
        nx = np.linalg.norm(x, axis=-1)
        r_len = np.sqrt(lam_len) * (nx - l)
        r_pri = np.sqrt(lam_prior) * (x - x0).reshape(F, -1)
        return np.concatenate([r_data, r_len, r_pri], 1), C, zs, sw, nx

    def cost(r):
        return (r * r).sum(1)

    for _ in range(n_outer):
        r, C, zs, sw, nx = residuals(x, T, l)
        c0 = cost(r)
        mu = np.full(F, 1e-3)
        for _ in range(n_iter):
            # Jacobian (F, m, n): data rows d p / d C (2 x 3) times d C / d (T, x)
            dp = np.zeros((F, J, 2, 3))
            dp[..., 0, 0] = 1.0 / zs
            dp[..., 1, 1] = 1.0 / zs
            dp[..., 0, 2] = -C[..., 0] / zs**2
            dp[..., 1, 2] = -C[..., 1] / zs**2
            dp = dp * sw[..., None]
            # d C_j / d x_b = D[b, j] I
            Jd = np.concatenate([dp, np.einsum("fjrc,bj->fjrbc", dp, Dt).reshape(F, J, 2, 3 * nb)], -1)
            Jd = Jd.reshape(F, 2 * J, n)
            u = x / np.maximum(nx, 1e-12)[..., None]
            Jl = np.zeros((F, nb, n))
            idx = 3 + 3 * np.arange(nb)
            for c in range(3):
                Jl[:, np.arange(nb), idx + c] = np.sqrt(lam_len) * u[..., c]
            Jp = np.zeros((F, 3 * nb, n))
            Jp[:, np.arange(3 * nb), 3 + np.arange(3 * nb)] = np.sqrt(lam_prior)
            Jm = np.concatenate([Jd, Jl, Jp], 1)
            A = np.swapaxes(Jm, 1, 2) @ Jm
            g = np.einsum("fmn,fm->fn", Jm, r)
            diag = np.einsum("fii->fi", A)
            step = -np.linalg.solve(A + (mu[:, None] * np.maximum(diag, 1e-12))[..., None] * np.eye(n), g[..., None])[..., 0]
            T_new = T + step[:, :3]
            x_new = x + step[:, 3:].reshape(F, nb, 3)
            r_new, C_new, zs_new, sw_new, nx_new = residuals(x_new, T_new, l)
            c1 = cost(r_new)
            ok = (c1 < c0) & np.isfinite(c1) & (C_new[..., 2] > 0).all(1)
            T = np.where(ok[:, None], T_new, T)
            x = np.where(ok[:, None, None], x_new, x)
            mu = np.where(ok, mu * 0.3, mu * 10.0)
            r, C, zs, sw, nx = residuals(x, T, l)
            c0 = cost(r)
        hist["cost"].append(float(c0.sum()))
        l = np.linalg.norm(x, axis=-1).mean(0)
    return x, T, l, hist
