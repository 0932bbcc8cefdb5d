import warnings

import numpy as np
import pytest

from chainspace import ConvergenceWarning, KinematicChain, TrackError
from chainspace.reconstruction.pipeline import Reconstruction, reconstruct
from chainspace.io.datasets import human17
from chainspace.metrics import error_3d
from chainspace.synthetic.views import observe, orbit_cameras, swing_motion


@pytest.fixture(scope="module")
def chain():
    return human17()


def _walkish(chain, F=90, noise=0.0, seed=0, sweep=10.0):
    X = swing_motion(chain, F, fps=120.0, seed=seed)
    P = orbit_cameras(F, scale=400.0, sweep_deg=sweep, seed=seed)
    W = observe(X, P, translations=[450.0, 450.0], noise_px=noise, seed=seed + 1)
    return X, W


def test_rigid_chain_under_strong_camera_motion_is_recovered(chain):
    rng = np.random.default_rng(0)
    X = np.broadcast_to(chain.rest_pose + 0.05 * rng.normal(size=chain.rest_pose.shape), (60, 17, 3))
    P = orbit_cameras(60, sweep_deg=120.0, elevation_deg=20.0, scale=400.0, seed=0)
    W = observe(X, P, translations=[450.0, 450.0])
    rec = reconstruct(W, chain, init_pose=X[0] * 1.0, method="rigid")
    # rigid factorization: exact up to scale (set by the initial pose, here the truth)
    assert error_3d(rec.poses, X) < 1e-3
    for m in ("kcs", "default"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            r = reconstruct(W, chain, init_pose=X[0], method=m)
        assert error_3d(r.poses, X) < 1e-3, m


def test_result_fields_shapes_units_and_reprojection(chain):
    X, W = _walkish(chain)
    rec = reconstruct(W, chain, truth=X)
    F, J = W.shape[:2]
    assert isinstance(rec, Reconstruction)
    assert rec.poses.shape == (F, J, 3) and rec.cameras.shape == (F, 2, 3)
    assert rec.translations.shape == (F, 2) and rec.bone_lengths.shape == (chain.n_links,)
    assert rec.tracks.shape == (F, J, 2) and rec.confidence is None and rec.method == "default"
    # tracks ~= poses @ cameras^T + translations
    pred = np.einsum("fij,fkj->fki", rec.cameras, rec.poses) + rec.translations[:, None]
    assert np.sqrt(((pred - W) ** 2).sum(-1).mean()) == pytest.approx(rec.reprojection_error())
    assert rec.reprojection_error() < 3.0
    # units of the rest pose (metres): bone lengths within 20 % of the truth's
    true_len = chain.bone_lengths(X[0])
    assert np.all(np.abs(rec.bone_lengths - true_len) < 0.2 * true_len + 0.02)
    for stage in ("kcs", "refine"):
        assert len(rec.history[stage]["reprojection"]) >= 2
        assert len(rec.history[stage]["error_3d"]) == len(rec.history[stage]["reprojection"])
    assert set(rec.timings) == {"kcs", "refine"}
    assert "Reconstruction('default'" in repr(rec)
    # the pipeline improves on the initial pose alone
    assert error_3d(rec.poses, X) < error_3d(np.broadcast_to(chain.rest_pose, X.shape), X)


def test_refinement_objective_is_monotone_in_the_pipeline(chain):
    X, W = _walkish(chain, noise=2.0, seed=3)
    rec = reconstruct(W, chain)
    h = np.array(rec.history["refine"]["objective"])
    assert np.all(np.diff(h) <= 1e-12 * h[0])


def test_deterministic(chain):
    X, W = _walkish(chain, noise=1.0, seed=4)
    a = reconstruct(W, chain, seed=1)
    b = reconstruct(W, chain, seed=1)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.cameras, b.cameras)


def test_nan_points_and_confidences(chain):
    X, W = _walkish(chain, seed=5)
    mask = np.random.default_rng(1).random(W.shape[:2]) < 0.1
    Wn = np.where(mask[..., None], np.nan, W)
    full = reconstruct(W, chain)
    part = reconstruct(Wn, chain)
    assert np.isfinite(part.poses).all()
    e_full, e_part = error_3d(full.poses, X), error_3d(part.poses, X)
    assert e_part < 1.5 * e_full + 0.01
    # known answer: confidence 0 on a garbage point is exactly a missing point
    Wg = np.where(mask[..., None], 1e5, W)
    conf = np.where(mask, 0.0, 1.0)
    same = reconstruct(Wg, chain, confidence=conf)
    np.testing.assert_allclose(same.poses, part.poses, atol=1e-9)
    # a third channel is read as the confidence
    third = reconstruct(np.concatenate([Wg, conf[..., None]], -1), chain)
    np.testing.assert_allclose(third.poses, part.poses, atol=1e-9)
    # an outlier point with low confidence barely matters
    Wo = W.copy()
    Wo[10, 3] += 300.0
    c = np.ones(W.shape[:2])
    c[10, 3] = 1e-3
    assert error_3d(reconstruct(Wo, chain, confidence=c).poses, X) < e_full + 0.005


@pytest.mark.parametrize(
    "make, msg",
    [
        (lambda W, c: (W[..., 0], None), "shape"),
        (lambda W, c: (W[:, :5], None), "joints"),
        (lambda W, c: (np.where(np.arange(17)[None, :, None] == 2, np.inf, W), None), "inf"),
        (lambda W, c: (np.where(np.arange(17)[None, :, None] == 4, np.nan, W), None), "never seen"),
        (lambda W, c: (W[:1], None), "at least 2 frames"),
        (lambda W, c: (np.ones_like(W), None), "constant"),
        (lambda W, c: (W, np.full(W.shape[:2], 2.0)), "[0, 1]"),
        (lambda W, c: (W, np.ones((3, 3))), "confidence has shape"),
        (lambda W, c: ([["a"]], None), "numeric"),
    ],
)
def test_bad_inputs_raise_track_error(chain, make, msg):
    X, W = _walkish(chain, F=10)
    tracks, conf = make(W, None)
    with pytest.raises(TrackError, match=None) as err:
        reconstruct(tracks, chain, confidence=conf)
    assert msg in str(err.value)


def test_other_bad_arguments(chain):
    X, W = _walkish(chain, F=10)
    with pytest.raises(TrackError, match="unknown method"):
        reconstruct(W, chain, method="magic")
    bare = KinematicChain(chain.joints, chain.bones)
    with pytest.raises(TrackError, match="rest pose"):
        reconstruct(W, bare)
    with pytest.raises(TrackError, match="init_pose"):
        reconstruct(W, chain, init_pose=np.zeros((3, 3)))
    with pytest.raises(TrackError, match="truth"):
        reconstruct(W, chain, truth=np.zeros((2, 17, 3)))


def test_non_convergence_is_flagged_and_warned(chain):
    X, W = _walkish(chain, noise=2.0)
    with pytest.warns(ConvergenceWarning):
        rec = reconstruct(W, chain, max_iter=1, tol=1e-12)
    assert rec.converged is False and "iteration limit" in rec.message


def test_real_walk_beats_the_initial_pose_and_kcs(chain):
    """Bundled CMU walk 35_01 (not the rest pose's subjects), one low-motion camera path, 2 px noise."""
    from chainspace.io.datasets import cmu_walk
    from chainspace.synthetic.views import scale_for_span

    X = cmu_walk(35, 1)
    P = orbit_cameras(len(X), scale=scale_for_span(X, 720.0), seed=7)
    W = observe(X, P, translations=[450.0, 450.0], noise_px=2.0, seed=8)
    e_init = error_3d(np.broadcast_to(chain.rest_pose, X.shape), X)
    e_kcs = error_3d(reconstruct(W, chain, method="kcs").poses, X)
    e_def = error_3d(reconstruct(W, chain).poses, X)
    assert e_def < 0.6 * e_init and e_def < e_kcs


def test_benchmark_table_format():
    from chainspace.bench.reconstruction import Row, format_table

    table = format_table([Row("walk35", 2.0, 4, {"chainspace default": (0.0201, 0.0195, 0.3)})])
    assert "| walk35 | 2 | 4 |" in table and "20.1 / 19.5 (0.30 s)" in table


def test_blas_threads_give_the_same_result_and_are_checked(chain):
    X, W = _walkish(chain, F=30)
    one = reconstruct(W, chain, method="kcs")
    every = reconstruct(W, chain, method="kcs", blas_threads=None)
    np.testing.assert_allclose(one.poses, every.poses, atol=1e-9)
    for bad in (0, 1.5, True, "2"):
        with pytest.raises(TrackError, match="blas_threads"):
            reconstruct(W, chain, blas_threads=bad)


def test_speed_table_format():
    from chainspace.bench.reconstruction import format_speed

    rows = [{"frames": n, "threads": t, "kcs_s": n / 2e4, "kcs_cpu_s": n / 2e4, "default_s": n / k,
             "default_cpu_s": n / k, "refine_s": n / 8e3, "kcs_bytes_per_frame": 4e3, "default_bytes_per_frame": 1.6e4,
             "kcs_iterations": 5, "refine_sweeps": 4}
            for n, k in ((1_000, 5e3), (100_000, 2.5e3)) for t in (1, None)]
    table = format_speed(rows)
    assert "| 100,000 | all cores | 5 | 5 | 20,000 | 20,000 | 5 | 8,000 | 4 | 40 | 40 | 2,500 | 2,500 | 4 | 16 |" in table
    assert "Linearity, BLAS threads 1: frames/s at 100,000 over 1,000 frames: KCS 1.00 (CPU 1.00), default 0.50" in table
