import numpy as np
import pytest

from chainspace.io.datasets import human17
from chainspace.reconstruction.kcs import bone_observations, kcs_factorize
from chainspace.reconstruction.refine import refine_bones
from chainspace.synthetic.views import observe, orbit_cameras, swing_motion


def _setup(noise=0.0, F=80, seed=0):
    chain = human17()
    X = swing_motion(chain, F, fps=120.0, seed=seed)
    P = orbit_cameras(F, scale=400.0, seed=seed)
    W = observe(X, P, noise_px=noise, seed=seed)
    c = np.ones(W.shape[:2])
    k = kcs_factorize(W, c, chain, chain.rest_pose)
    nb = chain.n_bones
    Wb, wb = bone_observations(chain, W, c)
    R = k.rotations
    x0 = np.einsum("fij,flj->fli", R, chain.bone_vectors(k.poses)[:, :nb])
    prior = np.einsum("fij,lj->fli", R, chain.bone_vectors(chain.rest_pose)[:nb])
    return chain, X, Wb[:, :nb], wb[:, :nb], k.scales, prior, x0


@pytest.mark.parametrize("noise", [0.0, 3.0])
def test_objective_never_increases(noise):
    _, _, Wb, wb, s, prior, x0 = _setup(noise)
    r = refine_bones(Wb, wb, s, prior, x0, max_iter=8, tol=0.0)
    h = np.array(r.history["objective"])
    assert len(h) == 1 + 3 * r.n_iter
    assert np.all(np.diff(h) <= 1e-12 * h[0])
    assert h[-1] < h[0]


def test_never_starts_worse_than_the_initial_pose():
    _, _, Wb, wb, s, prior, x0 = _setup(seed=1)
    bad = x0 + 5.0  # a terrible "KCS" start
    r = refine_bones(Wb, wb, s, prior, bad, max_iter=3)
    assert r.start != "kcs"
    from chainspace.reconstruction.refine import _Problem, _energy, _best_lengths  # the same objective
    pb = _Problem(Wb, wb, s, prior, float(np.median(s)) ** 2, 10.0, 4.0, 1e-3, r.history["delta"][0])
    assert r.history["objective"][-1] <= _energy(pb, prior, _best_lengths(prior)).sum() + 1e-9


def test_lengths_become_constant_and_data_is_kept():
    chain, X, Wb, wb, s, prior, x0 = _setup()
    r = refine_bones(Wb, wb, s, prior, x0, max_iter=10)
    L = np.linalg.norm(r.bones, axis=-1)
    cv = L.std(0) / L.mean(0)
    L0 = np.linalg.norm(x0, axis=-1)
    assert cv.mean() < 0.25 * (L0.std(0) / L0.mean(0)).mean()
    # in-image parts still match the 2D bones (px)
    rep = np.linalg.norm(s[:, None, None] * r.bones[..., :2] - Wb, axis=-1)
    assert np.median(rep) < 1.0


@pytest.mark.parametrize("F", [1, 2, 3, 4, 5, 7, 10, 11])
def test_viterbi_signs_are_the_exact_minimiser(F):
    """The blocked min-plus Viterbi equals brute force over all 2^F sign sequences."""
    import itertools

    from chainspace.reconstruction.refine import _viterbi

    rng = np.random.default_rng(F)
    n, k_acc = 3, 2.0
    m = np.abs(rng.normal(size=(n, F)))
    z = np.stack([m, -m])  # (2, n, F)
    unary = (z - rng.normal(size=(1, n, F))) ** 2

    def cost(sig, b):
        zz = np.where(np.array(sig) == 0, m[b], -m[b])
        acc = zz[2:] - 2 * zz[1:-1] + zz[:-2] if F > 2 else np.zeros(0)
        return unary[np.array(sig), b, np.arange(F)].sum() + k_acc * (acc**2).sum()

    got = _viterbi(unary, z, k_acc)
    assert got.shape == (n, F)
    for b in range(n):
        best = min(cost(sig, b) for sig in itertools.product((0, 1), repeat=F))
        assert cost(tuple(got[b]), b) == pytest.approx(best, rel=1e-12, abs=1e-12)


def test_blocks_of_frames_give_the_whole_sequences_numbers(monkeypatch):
    """The objective and the Gauss-Newton step are computed blocks.FRAME_BLOCK frames at a time (for the
    cache): blocks of 7 frames, whose accelerations and parent bones reach across block boundaries,
    give what one block of all frames gives."""
    import chainspace.blocks as blocks
    import chainspace.reconstruction.refine as R

    from chainspace.reconstruction.pipeline import _prior_parents

    chain, _, Wb, wb, s, prior, x0 = _setup(noise=2.0, F=40)
    wb = wb.copy()
    wb[5:9, 3] = 0.0  # a bone unseen across a block boundary
    pb = R._Problem(Wb, wb, s, prior, float(np.median(s)) ** 2, 10.0, 0.5, 1e-3, 3.0, _prior_parents(chain))
    l = R._best_lengths(x0)
    x = x0 * 1.05
    out = {}
    for block in (7, 10_000):
        monkeypatch.setattr(blocks, "FRAME_BLOCK", block)
        out[block] = (R.objective_terms(pb, x, l), R.objective_terms(pb, x, l, [2, 5]), R._gauss_newton(pb, x, l),
                      pb.prior(x))
    for a, b in zip(out[7][:2], out[10_000][:2]):
        for k in a:
            assert np.allclose(a[k], b[k], rtol=1e-12, atol=0), k
    assert np.array_equal(out[7][2], out[10_000][2])
    assert np.array_equal(out[7][3], out[10_000][3])


def test_gauss_newton_step_in_groups_of_bones_equals_one_solve(monkeypatch):
    """The Gauss-Newton step's banded solves take the bones in groups (SOLVE_GROUP unknowns): one bone
    a group gives the step of one solve for all bones (the groups' ridges, 1e-12 of their largest
    diagonal, differ in the last digits only)."""
    import chainspace.reconstruction.refine as R

    from chainspace.reconstruction.pipeline import _prior_parents

    chain, _, Wb, wb, s, prior, x0 = _setup(noise=2.0, F=40)
    pb = R._Problem(Wb, wb, s, prior, float(np.median(s)) ** 2, 10.0, 0.5, 1e-3, 3.0, _prior_parents(chain))
    l = R._best_lengths(x0)
    x = x0 * 1.05
    steps = {}
    for group in (1, 10**9):
        monkeypatch.setattr(R, "SOLVE_GROUP", group)
        steps[group] = R._gauss_newton(pb, x, l) - x
    assert np.abs(steps[1]).max() > 1e-3 * np.abs(x).max()  # a real step
    np.testing.assert_allclose(steps[1], steps[10**9], rtol=1e-9, atol=1e-9 * np.abs(steps[1]).max())
