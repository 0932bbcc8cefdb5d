import numpy as np
import pytest

from chainspace.io.datasets import human17
from chainspace.reconstruction.kcs import kcs_factorize
from chainspace.metrics import error_3d
from chainspace.synthetic.views import observe, orbit_cameras, swing_motion


def _case(noise=0.0, F=90, seed=0):
    chain = human17()
    X = swing_motion(chain, F, fps=120.0, seed=seed)
    P = orbit_cameras(F, scale=400.0, seed=seed)
    W = observe(X, P, translations=[450.0, 450.0], noise_px=noise, seed=seed)
    return chain, X, W


def test_algorithm1_fits_the_tracks_and_keeps_camera_constraints():
    chain, X, W = _case()
    r = kcs_factorize(W, np.ones(W.shape[:2]), chain, chain.rest_pose, truth=X, error_fn=error_3d)
    h = r.history["reprojection"]
    assert len(h) == r.n_iter + 1 and len(r.history["error_3d"]) == len(h)
    assert h[-1] < 0.05 * h[0]  # the deformation explains the tracks
    assert h[-1] < 2.0  # px, on a subject ~ 700 px tall
    assert r.poses.shape == X.shape and r.cameras.shape == (len(X), 2, 3)
    P = r.cameras
    np.testing.assert_allclose((P[:, 0] * P[:, 1]).sum(-1), 0, atol=1e-8 * r.scales.max() ** 2)
    np.testing.assert_allclose(np.linalg.norm(P, axis=-1), np.stack([r.scales] * 2, -1))
    # the 3D error improves on the initial pose (entry 0)
    assert r.history["error_3d"][-1] < r.history["error_3d"][0]


def test_nan_and_zero_confidence_are_the_same():
    chain, X, W = _case(F=40, seed=1)
    c = np.ones(W.shape[:2])
    Wn = W.copy()
    mask = np.random.default_rng(0).random(c.shape) < 0.1
    Wn[mask] = np.nan
    c0 = np.where(mask, 0.0, 1.0)
    Wg = np.where(mask[..., None], 1e4, W)  # garbage where the weight is 0
    a = kcs_factorize(Wn, c, chain, chain.rest_pose)
    b = kcs_factorize(Wg, c0, chain, chain.rest_pose)
    np.testing.assert_allclose(a.poses, b.poses, atol=1e-9)
    assert np.isfinite(a.poses).all()


def test_per_frame_weights_shortcut_matches_the_per_bone_gradient():
    """With one weight per frame the SVT steps use a cheaper gradient; it is the same gradient, so a
    confidence that differs by 1e-12 in one point (which takes the general path) changes nothing."""
    chain, X, W = _case(noise=1.0, F=60)
    c = np.ones(W.shape[:2])
    c[10] = 0.5  # still one weight per frame
    fast = kcs_factorize(W, c, chain, chain.rest_pose)
    c2 = c.copy()
    c2[20, 3] = 1.0 - 1e-12
    general = kcs_factorize(W, c2, chain, chain.rest_pose)
    assert fast.n_iter == general.n_iter
    np.testing.assert_allclose(fast.poses, general.poses, atol=1e-7)


def test_svt_matches_a_full_svd():
    """Singular value thresholding from the Gram matrix, through all directions or through the few
    kept ones (low thresholded rank), equals U max(sigma - tau, 0) V^T from a full SVD; the nuclear
    norm of the result is the thresholded one."""
    from chainspace.reconstruction.kcs import _gram, _shrinkage, _threshold

    A = np.random.default_rng(5).normal(size=(50, 3, 15)) * np.logspace(0, -3, 15)
    M = A.reshape(-1, 15)
    U, sig, Vt = np.linalg.svd(M, full_matrices=False)
    for tau in (0.0, 0.5 * sig[3], 0.5 * sig[12], 2.0 * sig[0]):  # all kept, a few (two thin products), most, none
        At = np.ascontiguousarray(A.transpose(1, 2, 0))  # frames last
        Vk, Vg, _ = _shrinkage(_gram(At), tau)
        out = _threshold(At, Vk, Vg, out=np.empty((3, 15, 50)))
        shrunk = np.maximum(sig - tau, 0.0)
        np.testing.assert_allclose(out.transpose(2, 0, 1).reshape(-1, 15), (U * shrunk) @ Vt, atol=1e-10 * sig[0])
        assert _shrinkage(M.T @ M, tau)[2] == pytest.approx(shrunk.sum())


@pytest.mark.parametrize("missing", [False, True])
def test_blocks_of_frames_give_the_whole_sequences_kcs(monkeypatch, missing):
    """The KCS stage's per-frame work and its FISTA steps' sweeps run blocks.FRAMES_LAST_BLOCK frames
    at a time: blocks of 7 frames give what one block of all frames gives (sums in another order:
    rounding)."""
    import chainspace.blocks as blocks

    chain, X, W = _case(noise=1.0, F=40)
    c = np.ones(W.shape[:2])
    if missing:
        c = np.random.default_rng(1).uniform(0.2, 1.0, W.shape[:2])
    out = {}
    for block in (7, 10_000):
        monkeypatch.setattr(blocks, "FRAMES_LAST_BLOCK", block)
        out[block] = kcs_factorize(W, c, chain, chain.rest_pose)
    assert out[7].n_iter == out[10_000].n_iter
    np.testing.assert_allclose(out[7].poses, out[10_000].poses, rtol=0, atol=1e-9 * np.abs(out[7].poses).max())
    np.testing.assert_allclose(out[7].cameras, out[10_000].cameras, rtol=1e-9)
    np.testing.assert_allclose(out[7].history["reprojection"], out[10_000].history["reprojection"], rtol=1e-9)


@pytest.mark.parametrize("uniform", [True, False])
def test_steps_in_camera_axes_equal_the_paper_step(uniform):
    """One FISTA step of _solve_A (run in camera axes, rotated per frame, frames last) is the textbook
    proximal gradient step in world axes: SVT(A - step * P^T ((P A S - R) w) S^T), the SVT by a full
    SVD."""
    from chainspace.cameras.weak import fit_cameras
    from chainspace.reconstruction.kcs import _solve_A, bone_observations

    chain, X, W = _case(noise=1.0, F=40)
    c = np.ones(W.shape[:2]) if uniform else np.random.default_rng(1).uniform(0.2, 1.0, W.shape[:2])
    Wb, wb = bone_observations(chain, W, c)
    B0 = (chain.C.T @ chain.rest_pose).T
    P, s, Rot = fit_cameras(Wb, B0.T, wb, return_rotation=True)
    rng = np.random.default_rng(2)
    S = rng.normal(size=(15, B0.shape[1]))
    A = rng.normal(size=(len(W), 3, 15)) * 0.1
    R = np.swapaxes(Wb, 1, 2) - P @ B0
    step = 1.0 / float((s**2 * wb.max(-1)).max() * np.linalg.norm(S, 2) ** 2)
    grad = np.swapaxes(P, 1, 2) @ (((P @ A @ S) - R) * wb[:, None, :]) @ S.T
    tau = 0.3 / step
    U, sig, Vt = np.linalg.svd((A - step * grad).reshape(-1, 15), full_matrices=False)
    want = ((U * np.maximum(sig - step * tau, 0.0)) @ Vt).reshape(A.shape)
    last = lambda a: np.ascontiguousarray(np.moveaxis(a, 0, -1))  # noqa: E731 - frames last
    got = _solve_A(last(A), last(Rot), s, S, last(R), wb.T, [tau])
    np.testing.assert_allclose(np.moveaxis(got, -1, 0), want, atol=1e-10 * np.abs(want).max())


def test_point_masks_equal_numpys_per_coordinate_forms():
    """where_seen, seen_points and complex_points (each point's two coordinates handled as one complex
    number) equal np.where(seen[..., None], points, fill), np.isfinite(points).all(-1) and x + iy where
    seen, on contiguous and strided arrays, with one coordinate missing, inf, and a NaN fill."""
    from chainspace.reconstruction.kcs import complex_points, seen_points, where_seen

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(6, 5, 2)) * 1e3
    pts[0, 1, 0] = np.nan
    pts[2, 3, 1] = np.inf
    pts[4, 0] = np.nan
    for p in (pts, pts[:, ::2], np.asfortranarray(pts)):
        seen = np.isfinite(p).all(-1)
        assert np.array_equal(seen_points(p), seen)
        assert not seen.all() and seen.any()
        for fill in (0.0, np.nan):
            np.testing.assert_array_equal(where_seen(p, seen, fill), np.where(seen[..., None], p, fill))
        want = np.where(seen, p[..., 0], 0.0) + 1j * np.where(seen, p[..., 1], 0.0)
        np.testing.assert_array_equal(complex_points(p, seen), want)
