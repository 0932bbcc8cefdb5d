"""Every track format round-trips; bad files raise TrackError naming the file and line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from chainspace.chain import KinematicChain
from chainspace.errors import ChainspaceError, OutputExistsError, TrackError
from chainspace.io.tracks import BODY_25, COCO17, COCO18, MEDIAPIPE33, load_tracks, save_tracks

HUMAN17 = ["pelvis", "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle", "spine",
           "thorax", "neck", "head", "left_shoulder", "left_elbow", "left_wrist", "right_shoulder",
           "right_elbow", "right_wrist"]


def _human17() -> KinematicChain:
    bones = [("pelvis", "left_hip"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
             ("pelvis", "right_hip"), ("right_hip", "right_knee"), ("right_knee", "right_ankle"),
             ("pelvis", "spine"), ("spine", "thorax"), ("thorax", "neck"), ("neck", "head"),
             ("thorax", "left_shoulder"), ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
             ("thorax", "right_shoulder"), ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist")]
    return KinematicChain(HUMAN17, bones, name="human17")


def _tracks(F: int, names, seed: int = 0, missing: float = 0.2):
    rng = np.random.default_rng(seed)
    P = rng.uniform(10, 600, size=(F, len(names), 2))
    P[rng.random((F, len(names))) < missing] = np.nan
    C = np.round(rng.uniform(0.05, 1.0, size=(F, len(names))), 3)
    C[np.isnan(P[..., 0])] = 0.0
    return P, C


def test_npz_names_under_another_key_are_refused(tmp_path):
    """Names stored as 'joints' instead of 'names': read in array order they would put every joint in
    another's place (the count still matches), so the file is refused, naming the key."""
    P, _ = _tracks(4, HUMAN17, missing=0.0)
    path = tmp_path / "t.npz"
    np.savez(path, tracks=P[:, ::-1], joints=np.array(HUMAN17[::-1]))
    with pytest.raises(TrackError, match=r"t.npz: no 'names' array, but 'joints' holds 17 strings"):
        load_tracks(path, chain=_human17())


def test_a_named_point_the_chain_lacks_is_reported(tmp_path):
    """A tracks column that no chain joint takes (a tool marker) is left out with a warning naming it;
    a detector's own extra points (COCO's eyes and ears on human17) are left out without one."""
    import warnings

    P, C = _tracks(4, HUMAN17 + ["tool_marker"], missing=0.0)
    path = tmp_path / "t.csv"
    save_tracks(path, P, HUMAN17 + ["tool_marker"], C)
    with pytest.warns(UserWarning, match=r"t.csv: 1 tracked point not in the chain human17, left out: tool_marker"):
        Q, _, names = load_tracks(path, chain=_human17())
    np.testing.assert_array_equal(Q, P[:, :17])
    P, C = _tracks(4, COCO17, missing=0.0)
    save_tracks(tmp_path / "c.json", P, list(COCO17), C, format="coco")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_tracks(tmp_path / "c.json", chain=_human17())


def test_points_a_selection_left_out_and_misspelt_names_are_told_apart(tmp_path):
    """Tracks of points the chain's selection dropped are said to be unselected (no extra-frame advice);
    a name the chain lacks that is close to an untracked joint gets a "did you mean"."""
    links = ["base", "link_1", "link_2", "link_3", "tool"]
    arm = KinematicChain(links, list(zip(links, links[1:])), name="arm")
    P, C = _tracks(4, links, missing=0.0)
    save_tracks(tmp_path / "t.csv", P, links, C)
    with pytest.warns(UserWarning) as caught:
        load_tracks(tmp_path / "t.csv", chain=arm.subset(["base", "link_2", "tool"]))
    (message,) = [str(w.message) for w in caught]
    assert message.endswith("t.csv: 2 tracked points not selected for the chain arm (links=, chain.subset), "
                            "left out: link_1, link_3")
    names = [n if n != "link_2" else "lnk_2" for n in links]
    save_tracks(tmp_path / "typo.csv", P, names, C)
    with pytest.warns(UserWarning, match=r"1 tracked point not in the chain arm, left out: lnk_2 "
                                         r"\(did you mean 'link_2'\? a point on a robot link"):
        load_tracks(tmp_path / "typo.csv", chain=arm)


@pytest.mark.parametrize("fmt,suffix,names", [
    ("csv", ".csv", ["a", "b", "c"]),
    ("npz", ".npz", ["a", "b", "c"]),
    ("npy", ".npy", None),
    ("coco", ".json", list(COCO17)),
    ("openpose", "", list(BODY_25)),
    ("openpose", "", list(COCO18)),
    ("mediapipe", ".json", list(MEDIAPIPE33)),
])
@pytest.mark.parametrize("with_conf", [True, False])
def test_round_trip(tmp_path, fmt, suffix, names, with_conf):
    J = 4 if names is None else len(names)
    P, C = _tracks(6, names or range(J))
    path = tmp_path / f"tracks{suffix}"
    save_tracks(path, P, names or [f"joint{j}" for j in range(J)], C if with_conf else None, format=fmt,
                image_size=(640, 480) if fmt == "mediapipe" else None)
    P2, C2, names2 = load_tracks(path, format=fmt)
    np.testing.assert_allclose(P2, P, rtol=1e-9, atol=1e-9 if fmt != "mediapipe" else 1e-6)
    assert names2 == (names or [f"joint{j}" for j in range(J)])
    if with_conf:
        np.testing.assert_allclose(C2, C, atol=1e-12)
    elif fmt in ("csv", "npz", "npy", "coco"):
        assert C2 is None
    else:  # formats that always carry a score: 1 where seen, 0 where missing
        np.testing.assert_array_equal(C2, np.where(np.isnan(P[..., 0]), 0.0, 1.0))


def test_format_is_guessed_from_path(tmp_path):
    P, C = _tracks(3, COCO17, missing=0)
    save_tracks(tmp_path / "c.json", P, COCO17, C)
    save_tracks(tmp_path / "op", P, COCO17, C)  # a folder: OpenPose BODY_25 layout
    assert load_tracks(tmp_path / "c.json")[2] == list(COCO17)
    P2, _, names = load_tracks(tmp_path / "op")
    assert names == list(BODY_25)
    np.testing.assert_allclose(P2[:, BODY_25.index("LShoulder")], P[:, COCO17.index("left_shoulder")])
    assert np.isnan(P2[:, BODY_25.index("MidHip")]).all()


def test_coco_visibility_flags(tmp_path):
    kp = [[10, 20, 2] * 17, [0, 0, 0] + [5, 6, 1] * 16]
    (tmp_path / "gt.json").write_text(json.dumps({"annotations": [
        {"image_id": 500, "keypoints": kp[1]}, {"image_id": 7, "keypoints": kp[0]}]}))
    P, C, names = load_tracks(tmp_path / "gt.json")
    assert C is None and P.shape == (2, 17, 2)  # image ids sorted: 7 then 500
    np.testing.assert_allclose(P[0], np.tile([10, 20], (17, 1)))
    assert np.isnan(P[1, 0]).all() and np.allclose(P[1, 1:], [5, 6])


def test_mapping_to_chain_by_name_alias_and_midpoint(tmp_path):
    chain = _human17()
    P, C = _tracks(5, BODY_25, missing=0)
    save_tracks(tmp_path / "op", P, BODY_25, C)
    T, W, names = load_tracks(tmp_path / "op", chain=chain)
    assert names == HUMAN17 and T.shape == (5, 17, 2) and W.shape == (5, 17)
    b = {n: P[:, i] for i, n in enumerate(BODY_25)}
    np.testing.assert_allclose(T[:, HUMAN17.index("left_knee")], b["LKnee"])
    np.testing.assert_allclose(T[:, HUMAN17.index("pelvis")], b["MidHip"])  # alias beats midpoint
    np.testing.assert_allclose(T[:, HUMAN17.index("thorax")], b["Neck"])
    np.testing.assert_allclose(T[:, HUMAN17.index("head")], b["Nose"])
    np.testing.assert_allclose(T[:, HUMAN17.index("spine")], (b["MidHip"] + b["Neck"]) / 2)
    # COCO-17 has no pelvis: the midpoint of the hips stands in, with the lower confidence
    P, C = _tracks(5, COCO17, missing=0)
    save_tracks(tmp_path / "c.json", P, COCO17, C)
    T, W, _ = load_tracks(tmp_path / "c.json", chain=chain)
    lh, rh = COCO17.index("left_hip"), COCO17.index("right_hip")
    np.testing.assert_allclose(T[:, 0], (P[:, lh] + P[:, rh]) / 2)
    np.testing.assert_allclose(W[:, 0], np.minimum(C[:, lh], C[:, rh]))
    assert np.isfinite(T).all()


def test_chain_joints_not_in_file_are_nan(tmp_path):
    chain = _human17()
    P, _ = _tracks(3, ["left_knee", "right_knee"], missing=0)
    save_tracks(tmp_path / "t.csv", P, ["left_knee", "right_knee"])
    T, C, _ = load_tracks(tmp_path / "t.csv", chain=chain)
    assert C is None and np.isfinite(T[:, [2, 5]]).all() and np.isnan(np.delete(T, [2, 5], axis=1)).all()
    save_tracks(tmp_path / "u.csv", P, ["foo", "bar"])
    with pytest.raises(TrackError, match="no joint name.*foo"):
        load_tracks(tmp_path / "u.csv", chain=chain)


def test_confidence_zero_keeps_the_point(tmp_path):
    P, C = _tracks(2, ["a", "b"], missing=0)
    C[0, 1] = 0.0
    save_tracks(tmp_path / "t.csv", P, ["a", "b"], C)
    P2, C2, _ = load_tracks(tmp_path / "t.csv")
    assert np.isfinite(P2[0, 1]).all() and C2[0, 1] == 0.0


@pytest.mark.parametrize("content,match", [
    ("", "empty"),
    ("frame,joint,x,y\n", "no data rows"),
    ("frame,joint,u,v\n0,a,1,2\n", r"t\.csv:1: wrong columns"),
    ("frame,joint,x,y\n0,a,1,2\n1,a,oops,2\n", r"t\.csv:3: malformed"),
    ("frame,joint,x,y\n0,a,1,2\n1,a,1\n", r"t\.csv:3: expected 4 fields"),
    ("frame,joint,x,y\n0,a,inf,2\n", r"t\.csv:2: infinite"),
    ("frame,joint,x,y\n0,a,1,2\n0,a,1,2\n", r"t\.csv:3: joint 'a' in frame 0 appears twice"),
    ("frame,joint,x,y,confidence\n0,a,1,2,1.5\n", r"confidence 1.5 of joint 'a' in frame 0"),
    ("frame,joint,x,y\n0,a,,\n", "no point"),
    ("frame,joint,x,y\n0,a,1,2\n999999999,a,1,2\n", "frame numbers reach 999999999"),
])
def test_bad_csv(tmp_path, content, match):
    (tmp_path / "t.csv").write_text(content)
    with pytest.raises(TrackError, match=match):
        load_tracks(tmp_path / "t.csv")


def test_bad_inputs(tmp_path):
    with pytest.raises(ChainspaceError, match="no such"):
        load_tracks(tmp_path / "missing.csv")
    (tmp_path / "t.xyz").write_text("1 2 3")
    with pytest.raises(TrackError, match="unknown track format"):
        load_tracks(tmp_path / "t.xyz")
    with pytest.raises(TrackError, match="unknown track format"):
        load_tracks(tmp_path / "t.xyz", format="xyz")
    (tmp_path / "b.json").write_text('[{"keypoints": [1, 2,\n 3}]')
    with pytest.raises(TrackError, match=r"b\.json:2: malformed JSON"):
        load_tracks(tmp_path / "b.json")
    np.save(tmp_path / "bad.npy", np.zeros((3, 4)))
    with pytest.raises(TrackError, match="expected \\(frames, joints, 2 or 3\\)"):
        load_tracks(tmp_path / "bad.npy")
    a = np.ones((2, 3, 2))
    a[1, 2, 0] = np.inf
    np.save(tmp_path / "inf.npy", a)
    with pytest.raises(TrackError, match="joint 'joint2' in frame 1 is infinite"):
        load_tracks(tmp_path / "inf.npy")
    with pytest.raises(TrackError, match="3 joints in the array but the chain"):
        load_tracks(tmp_path / "inf.npy", chain=_human17())
    (tmp_path / "mp.json").write_text(json.dumps([[{"x": 0.5, "y": 0.5}] * 33]))
    with pytest.raises(TrackError, match="image_size"):
        load_tracks(tmp_path / "mp.json", format="mediapipe")
    P, C, _ = load_tracks(tmp_path / "mp.json", format="mediapipe", image_size=(200, 100))
    np.testing.assert_allclose(P[0, 0], [100, 50])


def test_save_refuses_to_overwrite(tmp_path):
    P, _ = _tracks(2, ["a"], missing=0)
    save_tracks(tmp_path / "t.csv", P, ["a"])
    with pytest.raises(OutputExistsError):
        save_tracks(tmp_path / "t.csv", P, ["a"])
    save_tracks(tmp_path / "t.csv", P * 2, ["a"], overwrite=True)
    np.testing.assert_allclose(load_tracks(tmp_path / "t.csv")[0], P * 2)
    with pytest.raises(TrackError, match="shape"):
        save_tracks(tmp_path / "x.csv", np.zeros((2, 3)), ["a", "b", "c"])


hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_cells = st.one_of(st.integers(-3, 5).map(str), st.sampled_from(["", "nan", "inf", "-1e400", "a", "left_hip",
                                                                  "0.5", "1e3", " ", '"x,y"']))
_csv = st.lists(st.lists(_cells, min_size=0, max_size=6).map(",".join), max_size=8).map(
    lambda rows: "\n".join(["frame,joint,x,y,confidence"] + rows))
_json = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=True),
                               st.text(max_size=4)),
                     lambda inner: st.one_of(st.lists(inner, max_size=5),
                                             st.dictionaries(st.sampled_from(
                                                 ["people", "pose_keypoints_2d", "keypoints", "frame",
                                                  "image_id", "annotations", "frames", "landmarks", "x", "y",
                                                  "visibility", "image_width", "image_height"]), inner,
                                                 max_size=4)), max_leaves=20)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.one_of(_csv, st.text(max_size=60)))
def test_fuzz_csv_raises_only_track_errors(tmp_path, text):
    (tmp_path / "f.csv").write_text(text)
    try:
        P, C, names = load_tracks(tmp_path / "f.csv")
    except ChainspaceError:
        return
    assert P.ndim == 3 and P.shape[2] == 2 and len(names) == P.shape[1]
    assert not np.isinf(P).any() and (C is None or ((C >= 0) & (C <= 1)).all())


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=_json, fmt=st.sampled_from([None, "coco", "mediapipe", "openpose"]))
def test_fuzz_json_raises_only_track_errors(tmp_path, doc, fmt):
    (tmp_path / "f.json").write_text(json.dumps(doc))
    try:
        P, C, names = load_tracks(tmp_path / "f.json", format=fmt, image_size=(640, 480))
    except ChainspaceError:
        return
    assert P.ndim == 3 and P.shape[2] == 2 and len(names) == P.shape[1] and not np.isinf(P).any()
