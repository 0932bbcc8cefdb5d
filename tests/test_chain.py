"""KinematicChain: the matrices C and D, subsets and re-ordering, and every kind of bad chain."""

from __future__ import annotations

import numpy as np
import pytest

from chainspace.chain import KinematicChain
from chainspace.errors import ChainspaceError, DescriptionError, TrackError

# A small human-like tree: pelvis -> spine -> neck -> head, two arms from the neck, two legs.
JOINTS = ["pelvis", "spine", "neck", "head", "l_sho", "l_elb", "l_wri", "r_sho", "r_elb", "r_wri",
          "l_hip", "l_kne", "r_hip", "r_kne"]
BONES = [("pelvis", "spine"), ("spine", "neck"), ("neck", "head"), ("neck", "l_sho"),
         ("l_sho", "l_elb"), ("l_elb", "l_wri"), ("neck", "r_sho"), ("r_sho", "r_elb"),
         ("r_elb", "r_wri"), ("pelvis", "l_hip"), ("l_hip", "l_kne"), ("pelvis", "r_hip"),
         ("r_hip", "r_kne")]


@pytest.fixture
def chain() -> KinematicChain:
    return KinematicChain(JOINTS, BONES, name="toy")


def random_tree(rng: np.random.Generator, n: int) -> KinematicChain:
    """A random tree over n joints, joints and bones listed in a shuffled order."""
    names = [f"j{i}" for i in range(n)]
    bones = [(names[int(rng.integers(i))], names[i]) for i in range(1, n)]
    perm = rng.permutation(n)
    order = rng.permutation(len(bones))
    return KinematicChain([names[i] for i in perm], [bones[k] for k in order])


def test_bones_are_x_times_c_and_d_rebuilds_the_pose(chain, rng):
    X = rng.normal(size=(3, chain.n_joints))  # the paper's 3 x J pose
    B = X @ chain.C
    root = chain.joint_index(chain.root)
    np.testing.assert_allclose(B @ chain.D, X - X[:, [root]], atol=1e-12)
    # each bone vector is child minus parent
    for k, (a, b) in enumerate(chain.bones):
        np.testing.assert_allclose(B[:, k], X[:, chain.joint_index(b)] - X[:, chain.joint_index(a)])


@pytest.mark.parametrize("seed", range(8))
def test_c_d_round_trip_on_random_trees(seed):
    rng = np.random.default_rng(seed)
    chain = random_tree(rng, int(rng.integers(2, 40)))
    poses = rng.normal(size=(5, chain.n_joints, 3))  # frames-first
    rebuilt = chain.poses_from_bones(chain.bone_vectors(poses))
    root = chain.joint_index(chain.root)
    np.testing.assert_allclose(rebuilt, poses - poses[:, [root]], atol=1e-12)
    assert chain.C.shape == (chain.n_joints, chain.n_joints - 1)
    assert chain.D.shape == (chain.n_joints - 1, chain.n_joints)
    assert (np.abs(chain.C).sum(axis=0) == 2).all() and (chain.C.sum(axis=0) == 0).all()


def test_d_marks_the_bones_on_the_path_from_the_root(chain):
    D = chain.D
    wrist = chain.joint_index("l_wri")
    on_path = {chain.bones[k] for k in np.flatnonzero(D[:, wrist])}
    assert on_path == {("pelvis", "spine"), ("spine", "neck"), ("neck", "l_sho"), ("l_sho", "l_elb"),
                       ("l_elb", "l_wri")}
    assert not D[:, chain.joint_index("pelvis")].any()


def test_rigid_links_add_columns_to_c_only(chain, rng):
    rigid = chain.with_rigid_links([("l_wri", "r_wri"), ("l_kne", "r_kne")])
    assert rigid.C.shape == (chain.n_joints, chain.n_bones + 2)
    np.testing.assert_array_equal(rigid.C[:, : chain.n_bones], chain.C)
    np.testing.assert_array_equal(rigid.D, chain.D)
    X = rng.normal(size=(3, chain.n_joints))
    B = X @ rigid.C
    np.testing.assert_allclose(B[:, -2], X[:, chain.joint_index("r_wri")] - X[:, chain.joint_index("l_wri")])
    # poses_from_bones ignores the rigid-link columns
    np.testing.assert_allclose(rigid.poses_from_bones(B.T), (X - X[:, [0]]).T, atol=1e-12)
    assert rigid.links[-2:] == (("l_wri", "r_wri"), ("l_kne", "r_kne"))


def test_bone_lengths_and_shapes(chain, rng):
    poses = rng.normal(size=(4, 2, chain.n_joints, 3))
    lengths = chain.bone_lengths(poses)
    assert lengths.shape == (4, 2, chain.n_bones)
    k = chain.bones.index(("neck", "head"))
    np.testing.assert_allclose(
        lengths[..., k], np.linalg.norm(poses[..., 3, :] - poses[..., 2, :], axis=-1)
    )
    with pytest.raises(TrackError, match="expected"):
        chain.bone_vectors(np.zeros((4, chain.n_joints + 1, 3)))


def test_subset_joins_to_the_nearest_kept_ancestor(chain, rng):
    sub = chain.subset(["l_wri", "pelvis", "neck", "l_sho"])
    assert sub.joints == ("l_wri", "pelvis", "neck", "l_sho")  # the order given
    assert set(sub.bones) == {("pelvis", "neck"), ("neck", "l_sho"), ("l_sho", "l_wri")}
    assert sub.root == "pelvis"
    poses = rng.normal(size=(3, chain.n_joints, 3))
    picked = poses[:, [chain.joint_index(j) for j in sub.joints]]
    # a bone of the subset is the sum of the dropped bones along its path
    k = sub.bones.index(("l_sho", "l_wri"))
    np.testing.assert_allclose(sub.bone_vectors(picked)[:, k], picked[:, 0] - picked[:, 3])
    np.testing.assert_allclose(sub.poses_from_bones(sub.bone_vectors(picked)),
                               picked - picked[:, [1]], atol=1e-12)


def test_subset_keeps_rest_pose_and_rigid_links(chain, rng):
    rest = rng.normal(size=(chain.n_joints, 3))
    full = chain.with_rest_pose(rest).with_rigid_links([("l_wri", "r_wri"), ("l_kne", "r_kne")])
    sub = full.subset(["pelvis", "neck", "l_wri", "r_wri"])
    np.testing.assert_array_equal(sub.rest_pose, rest[[0, 2, 6, 9]])
    assert sub.rigid_links == (("l_wri", "r_wri"),)


def test_subset_without_a_common_root_raises(chain):
    with pytest.raises(DescriptionError, match="l_wri.*r_wri|no common root"):
        chain.subset(["l_wri", "r_wri"])
    with pytest.raises(DescriptionError, match="nope"):
        chain.subset(["pelvis", "nope"])


def test_reorder_maps_named_values_into_chain_order(chain, rng):
    names = ["r_wri", "head", "unknown_point", "pelvis"]
    tracks = rng.normal(size=(6, len(names), 2))
    out = chain.reorder(tracks, names)
    assert out.shape == (6, chain.n_joints, 2)
    np.testing.assert_array_equal(out[:, chain.joint_index("r_wri")], tracks[:, 0])
    np.testing.assert_array_equal(out[:, chain.joint_index("pelvis")], tracks[:, 3])
    assert np.isnan(out[:, chain.joint_index("l_elb")]).all()
    conf = chain.reorder(rng.uniform(size=(6, 4)), names, axis=-1, fill=0.0)
    assert conf.shape == (6, chain.n_joints) and conf[:, chain.joint_index("spine")].max() == 0.0


@pytest.mark.parametrize(
    ("names", "message"),
    [(["a", "b"], "2 names"), (["head", "head", "neck"], "twice"), (["x", "y", "z"], "none of")],
)
def test_reorder_rejects_bad_names(chain, names, message):
    n = 3
    with pytest.raises(TrackError, match=message):
        chain.reorder(np.zeros((2, n, 2)), names)


BAD_CHAINS = [
    ("unknown joint", ["a", "b"], [("a", "c")], None, "unknown joint 'c'"),
    ("duplicate joint", ["a", "b", "a"], [("a", "b")], None, "'a' appears twice"),
    ("cycle", ["r", "a", "b", "c"], [("r", "a"), ("a", "b"), ("b", "c"), ("c", "a")], None, "two parents"),
    ("pure cycle", ["a", "b", "c"], [("a", "b"), ("b", "c"), ("c", "a")], None, "cycle"),
    ("detached cycle", ["r", "a", "b"], [("a", "b"), ("b", "a")], None, "disconnected|cycle"),
    ("two parents", ["a", "b", "c"], [("a", "c"), ("b", "c")], None, "'c' has two parents"),
    ("disconnected", ["a", "b", "c", "d"], [("a", "b"), ("c", "d")], None, "disconnected.*a, c"),
    ("self bone", ["a", "b"], [("a", "a"), ("a", "b")], None, "'a' to itself"),
    ("not a pair", ["a", "b"], [("a",)], None, "not a .parent, child. pair"),
    ("no joints", [], [], None, "no joints"),
    ("one string", "abc", [], None, "not one string"),
    ("empty name", ["a", ""], [("a", "")], None, "invalid name"),
    ("rest pose shape", ["a", "b"], [("a", "b")], np.zeros((3, 3)), r"shape \(3, 3\)"),
    ("rest pose nan", ["a", "b"], [("a", "b")], [[0, 0, 0], [np.nan, 0, 0]], "joint 'b' is not finite"),
    ("rest pose text", ["a", "b"], [("a", "b")], [["x", 0, 0], [0, 0, 0]], "not numeric"),
]


@pytest.mark.parametrize(("kind", "joints", "bones", "rest", "message"), BAD_CHAINS, ids=[c[0] for c in BAD_CHAINS])
def test_bad_chains_raise_naming_the_element(kind, joints, bones, rest, message):
    with pytest.raises(DescriptionError, match=message) as info:
        KinematicChain(joints, bones, rest, source="toy.skel")
    assert isinstance(info.value, ChainspaceError)
    assert str(info.value).startswith("toy.skel: ")


@pytest.mark.parametrize(
    ("rigid", "message"),
    [([("a", "z")], "unknown joint 'z'"), ([("a", "b")], "repeats a bone"), ([("a", "c"), ("c", "a")], "given twice")],
)
def test_bad_rigid_links_raise(rigid, message):
    with pytest.raises(DescriptionError, match=message):
        KinematicChain(["a", "b", "c"], [("a", "b"), ("b", "c")], rigid_links=rigid)


def test_joint_index_names_the_unknown_joint_with_a_hint(chain):
    with pytest.raises(DescriptionError, match=r"unknown joint 'l_wrist'.*did you mean 'l_wri'"):
        chain.joint_index("l_wrist")


def test_public_functions_stay_functions_after_their_modules_load():
    # A submodule import binds the package attribute of the same name; no public function may share
    # its name with a submodule, or `chainspace.reconstruct` would become the module.
    import importlib

    import chainspace

    for name, module in chainspace._EXPORTS.items():
        importlib.import_module(f"chainspace.{module}")
        assert getattr(chainspace, name) is getattr(importlib.import_module(f"chainspace.{module}"), name), name
