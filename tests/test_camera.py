import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from chainspace import TrackError
from chainspace.cameras.weak import fit_cameras, project


def _case(F=40, L=12, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(F, L, 3))
    R = Rotation.random(F, random_state=seed).as_matrix()
    s = rng.uniform(50, 500, F)
    P = s[:, None, None] * R[:, :2]
    W = np.einsum("fij,flj->fli", P, B) + noise * rng.normal(size=(F, L, 2))
    return B, P, W


def test_exact_cameras_are_recovered():
    B, P, W = _case()
    np.testing.assert_allclose(fit_cameras(W, B), P, atol=1e-7 * np.abs(P).max())
    # column layout (F, 2, L) / (F, 3, L) as in the paper
    np.testing.assert_allclose(fit_cameras(np.swapaxes(W, 1, 2), np.swapaxes(B, 1, 2)), P, atol=1e-7 * np.abs(P).max())


def test_constraints_hold_under_noise_and_fit_beats_truth():
    B, P, W = _case(noise=5.0, seed=1)
    Pf, s, R = fit_cameras(W, B, return_rotation=True)
    np.testing.assert_allclose((Pf[:, 0] * Pf[:, 1]).sum(-1), 0.0, atol=1e-9 * s.max() ** 2)
    np.testing.assert_allclose(np.linalg.norm(Pf, axis=-1), np.stack([s, s], -1), rtol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    res = lambda Q: ((W - np.einsum("fij,flj->fli", Q, B)) ** 2).sum((1, 2))  # noqa: E731
    # the fitted camera is at least as good as the true one in every frame (a minimum)
    assert np.all(res(Pf) <= res(P) * (1 + 1e-9))


def test_weights_and_nan_ignore_corrupted_bones():
    B, P, W = _case(seed=2)
    Wc = W.copy()
    Wc[:, 0] += 1000.0
    w = np.ones(W.shape[:2])
    w[:, 0] = 0.0
    np.testing.assert_allclose(fit_cameras(Wc, B, w), P, atol=1e-6 * np.abs(P).max())
    Wn = W.copy()
    Wn[:, 0] = np.nan
    np.testing.assert_allclose(fit_cameras(Wn, B), P, atol=1e-6 * np.abs(P).max())


def test_frames_without_data_take_the_nearest_camera():
    B, P, W = _case(F=5, seed=3)
    W[2] = np.nan
    Pf = fit_cameras(W, B)
    assert np.isfinite(Pf).all()
    np.testing.assert_allclose(Pf[2], Pf[1])


def test_cameras_from_frames_last_moments_equal_fit_cameras():
    """The KCS stage's route (bone_moments of frames-last arrays, then fit_to_moments, warm-started)
    gives fit_cameras' cameras, on noisy data with weights, an unusable frame filled from its
    neighbour."""
    from chainspace.cameras.weak import bone_moments, fit_to_moments

    B, P, W = _case(noise=5.0, seed=4)
    w = np.random.default_rng(4).uniform(0.2, 1.0, W.shape[:2])
    w[7, 1:] = 0.0  # one bone left: frame 7 is filled
    W = np.where(w[..., None] > 0, W, 0.0)
    R0 = Rotation.random(len(W), random_state=5).as_matrix()
    for kw in ({}, {"R0": R0, "n_iter": 1}):
        Pf, s, R = fit_cameras(W, B, w, return_rotation=True, **kw)
        last = lambda a: np.ascontiguousarray(np.moveaxis(a, 0, -1))  # noqa: E731
        G, H = bone_moments(last(np.swapaxes(W, 1, 2)), last(np.swapaxes(B, 1, 2)), last(w))
        c0 = (w * (W**2).sum(-1)).sum(-1)
        R0e = last(kw["R0"]) if kw else None
        s2, R2 = fit_to_moments(G, H, c0, (w > 0).sum(-1) >= 2, R0=R0e, n_iter=kw.get("n_iter", 5))
        # the same arithmetic in another order: rounding, which the damped steps' cost tests amplify
        np.testing.assert_allclose(s2, s, rtol=1e-7)
        np.testing.assert_allclose(np.moveaxis(R2, -1, 0), R, atol=1e-7)
        np.testing.assert_allclose(R[7], R[6])


def test_bones_shared_by_every_frame_give_the_per_frame_answer():
    """One (L, 3) set of bones for every frame (moments as matrix products over the bones) fits the
    cameras that the same bones repeated per frame (F, L, 3) fit, with weights and a missing bone."""
    B, P, W = _case(noise=3.0, seed=6)
    Bs = B[0]
    W = np.einsum("fij,lj->fli", P, Bs) + np.random.default_rng(6).normal(size=W.shape)
    w = np.random.default_rng(7).uniform(0.2, 1.0, W.shape[:2])
    W[3, 2] = np.nan
    got = fit_cameras(W, Bs, w)
    np.testing.assert_allclose(got, fit_cameras(W, np.repeat(Bs[None], len(W), 0), w), rtol=1e-7, atol=1e-7 * np.abs(P).max())
    assert np.abs(got - P).max() < 0.05 * np.abs(P).max()


def test_project_and_shape_errors():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(3, 4, 3))
    P = rng.normal(size=(3, 2, 3))
    t = rng.normal(size=(3, 2))
    np.testing.assert_allclose(project(X, P, t), np.einsum("fij,fkj->fki", P, X) + t[:, None])
    with pytest.raises(TrackError):
        project(X, P[:, :, :2])
    with pytest.raises(TrackError):
        fit_cameras(np.zeros((3, 4, 2)), np.zeros((3, 5, 3)))


def test_closed_form_orthonormal_rows_are_the_svd_polar_factor():
    """The closed-form start (2 x 2 inverse square root) is U V^T of the SVD; rank-one and zero
    matrices, where it has no closed form, fall back to the SVD and still have orthonormal rows."""
    from chainspace.cameras.weak import _orthonormal_rows

    M = np.random.default_rng(3).normal(size=(200, 2, 3)) * np.logspace(-6, 6, 200)[:, None, None]
    M[0] = np.outer([1.0, 2.0], [0.0, 3.0, 4.0])
    M[1] = 0.0
    U, _, Vt = np.linalg.svd(M, full_matrices=False)
    Q = np.moveaxis(_orthonormal_rows(np.moveaxis(M, 0, -1)), -1, 0)  # entries first
    np.testing.assert_allclose(Q[2:], (U @ Vt)[2:], atol=1e-10)
    np.testing.assert_allclose(Q @ np.swapaxes(Q, 1, 2), np.broadcast_to(np.eye(2), (200, 2, 2)), atol=1e-10)


def test_written_out_cholesky_solves_the_gauss_newton_systems():
    """The 4 x 4 solve of a Gauss-Newton step (entries given as (F,) arrays, two of them zero as in
    the camera's normal matrix) equals np.linalg.solve, on systems whose unknowns differ in scale by 10^4."""
    from chainspace.cameras.weak import _solve_spd4

    rng = np.random.default_rng(4)
    F = 300
    J = rng.normal(size=(F, 8, 4)) * np.logspace(0, -4, 4)  # columns of very different scales
    A = np.swapaxes(J, 1, 2) @ J + 1e-9 * np.eye(4)
    A[:, 0, 3] = A[:, 3, 0] = A[:, 1, 2] = A[:, 2, 1] = 0.0
    A += np.abs(A).sum(-1)[..., None] * np.eye(4)  # keep it positive definite after the zeros
    b = rng.normal(size=(F, 4))
    N = [[A[:, i, j] if j <= i else None for j in range(4)] for i in range(4)]
    N[3][0], N[2][1] = 0.0, 0.0
    x = _solve_spd4(N, [b[:, i] for i in range(4)]).T  # (4, F): one row per unknown
    np.testing.assert_allclose(x, np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-10, atol=1e-12)
