"""Property-based fuzzing of every public entry point that reads user data (issue 6).

Description files (URDF, ASF, AMC, BVH, skeleton TOML/YAML) and track files (CSV, COCO JSON) are
made from small valid seeds by random edits (cuts, deleted/duplicated/swapped lines, nasty tokens,
random text); tracks given to :func:`chainspace.reconstruct` are drawn with NaN, inf, huge, tiny
and constant values, odd shapes and confidences. The property everywhere: the call returns a
sane result (finite where it promises finite) or raises :class:`chainspace.ChainspaceError`;
never another exception, never a hang (each example runs under an alarm).

``CHAINSPACE_FUZZ_EXAMPLES`` raises the number of examples per test (default 25) for a longer hunt.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import warnings
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from chainspace import ChainspaceError, KinematicChain

N_EXAMPLES = int(os.environ.get("CHAINSPACE_FUZZ_EXAMPLES", "25"))
HANG_SECONDS = 20  # a single example taking longer than this is a hang
FUZZ = settings(
    max_examples=N_EXAMPLES,
    deadline=None,  # the alarm below catches hangs; timings on a shared 2-core machine vary too much
    # deterministic in the suite; CHAINSPACE_FUZZ_RANDOM=1 explores new inputs on every run
    derandomize=not os.environ.get("CHAINSPACE_FUZZ_RANDOM"),
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                           HealthCheck.data_too_large],
    database=None,
)


@contextlib.contextmanager
def no_hang(seconds: int = HANG_SECONDS):
    """Fail (TimeoutError) instead of hanging when the body runs longer than ``seconds``."""
    if not hasattr(signal, "SIGALRM"):  # pragma: no cover - Windows
        yield
        return

    def alarm(signum, frame):
        raise TimeoutError(f"no answer after {seconds} s: a hang")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def only_chainspace_errors(call, *args, **kwargs):
    """Run ``call``; return its result, or None when it raised a ChainspaceError (the allowed failure)."""
    with no_hang(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return call(*args, **kwargs)
        except ChainspaceError as exc:
            assert str(exc).strip(), "a ChainspaceError without a message"
            return None


# ------------------------------------------------------------------------------------------ seeds
URDF_SEED = """<?xml version="1.0"?>
<robot name="arm3">
  <link name="base"/>
  <link name="upper"/>
  <link name="fore"/>
  <link name="hand"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.5" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-1.5" upper="1.5" effort="10" velocity="1"/>
  </joint>
  <joint name="elbow" type="revolute">
    <parent link="upper"/><child link="fore"/>
    <origin xyz="0.4 0 0" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="10" velocity="1"/>
  </joint>
  <joint name="wrist" type="continuous">
    <parent link="fore"/><child link="hand"/>
    <origin xyz="0.3 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/>
  </joint>
</robot>
"""

ASF_SEED = """# small Acclaim skeleton
:version 1.10
:name fuzz
:units
  mass 1.0
  length 0.45
  angle deg
:documentation
  made for fuzzing
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name lfemur
     direction 0 -1 0
     length 7.0
     axis 0 0 20 XYZ
    dof rx ry rz
    limits (-160.0 20.0)
           (-70.0 70.0)
           (-60.0 70.0)
  end
  begin
     id 2
     name ltibia
     direction 0 -1 0
     length 7.0
     axis 0 0 20 XYZ
    dof rx
    limits (-10.0 170.0)
  end
  begin
     id 3
     name spine
     direction 0 1 0
     length 5.0
     axis 0 0 0 XYZ
    dof rx ry rz
    limits (-30.0 30.0)
           (-30.0 30.0)
           (-30.0 30.0)
  end
:hierarchy
  begin
    root lfemur spine
    lfemur ltibia
  end
"""

AMC_SEED = """:FULLY-SPECIFIED
:DEGREES
1
root 1 17 -2 0.5 -8 -7
lfemur -20 4 -9
ltibia 22
spine 1 2 3
2
root 1.1 17.1 -2.1 0.6 -8.1 -7.1
lfemur -21 4.5 -9.5
ltibia 23
spine 1.5 2.5 3.5
3
root 1.2 17.2 -2.2 0.7 -8.2 -7.2
lfemur -22 5 -10
ltibia 24
spine 2 3 4
"""

BVH_SEED = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0.1 -0.4 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -0.4 0
    }
  }
  JOINT chest
  {
    OFFSET 0 0.3 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0.25 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 1 0 0 0 0 10 0 0 0 5 0
0.1 1 0 5 0 0 20 0 0 0 10 0
0.2 1 0 10 0 0 30 0 0 0 15 0
"""

TOML_SEED = """name = "fuzz"
units = "m"
up = "z"

[[joints]]
name = "root"
rest = [0.0, 0.0, 0.0]

[[joints]]
name = "a"
rest = [0.0, 0.0, 0.5]

[[joints]]
name = "b"
rest = [0.3, 0.0, 0.5]

[[joints]]
name = "c"
rest = [0.0, 0.3, 0.5]

[[bones]]
parent = "root"
child = "a"

[[bones]]
parent = "a"
child = "b"

[[bones]]
parent = "a"
child = "c"
"""

YAML_SEED = """name: fuzz
units: cm
up: y
joints:
  - {name: root, rest: [0, 0, 0]}
  - {name: a, rest: [0, 50, 0]}
  - {name: b, rest: [30, 50, 0]}
  - {name: c, rest: [0, 50, 30]}
bones:
  - [root, a]
  - [a, b]
  - [a, c]
rigid_links:
  - [b, c]
"""

CSV_SEED = """frame,joint,x,y,confidence
0,root,100,200,1
0,a,110,150,0.9
0,b,140,150,0.8
0,c,110,120,0.5
1,root,101,201,1
1,a,111,151,0.9
1,b,141,149,0.8
1,c,112,121,0.4
"""

COCO_SEED = """[{"image_id": 0, "category_id": 1, "score": 0.9, "keypoints": [
 10, 20, 2, 11, 21, 2, 12, 22, 2, 13, 23, 1, 14, 24, 2, 15, 25, 2, 16, 26, 2, 17, 27, 2, 18, 28, 2,
 19, 29, 2, 20, 30, 2, 21, 31, 2, 22, 32, 2, 23, 33, 2, 24, 34, 2, 25, 35, 2, 26, 36, 0]},
 {"image_id": 1, "category_id": 1, "score": 0.8, "keypoints": [
 10, 21, 2, 11, 22, 2, 12, 23, 2, 13, 24, 1, 14, 25, 2, 15, 26, 2, 16, 27, 2, 17, 28, 2, 18, 29, 2,
 19, 30, 2, 20, 31, 2, 21, 32, 2, 22, 33, 2, 23, 34, 2, 24, 35, 2, 25, 36, 2, 26, 37, 0]}]
"""

# Tokens that break parsers: numbers out of range, structure characters, names of the file's kind.
NASTY = ["", " ", "nan", "NaN", "inf", "-inf", "1e400", "-1", "0", "-0", "1e-320", "99999999999999999999",
         "0x1F", "1,5", "\x00", "\t", "\r", "\u00e9", "{", "}", "[", "]", "<", ">", "/>", '"', "'", "#", ":",
         "=", "-", "begin", "end", "root", "ROOT", "JOINT", "End Site", "OFFSET", "CHANNELS", "MOTION",
         "Frames:", "link", "joint", "[[joints]]", "[[bones]]", "name", "rest", ":root", ":bonedata",
         ":hierarchy", "dof", "length", "direction", "axis", "XYZ", "ZZZ", "rx", "tx"]


@st.composite
def mutated(draw, seed: str) -> str:
    """``seed`` after 1 to 4 random edits."""
    text = seed
    for _ in range(draw(st.integers(1, 4))):
        lines = text.split("\n")
        op = draw(st.sampled_from(["cut", "drop_line", "dup_line", "swap_lines", "token", "insert", "delete"]))
        if op == "cut":
            text = text[: draw(st.integers(0, len(text)))]
        elif op in ("drop_line", "dup_line", "swap_lines") and lines:
            i = draw(st.integers(0, len(lines) - 1))
            if op == "drop_line":
                del lines[i]
            elif op == "dup_line":
                lines.insert(i, lines[i])
            else:
                j = draw(st.integers(0, len(lines) - 1))
                lines[i], lines[j] = lines[j], lines[i]
            text = "\n".join(lines)
        elif op == "token":
            parts = re.split(r"(\s+|[<>\"=,\[\]{}/])", text)
            words = [k for k, p in enumerate(parts) if p and not p.isspace()]
            if words:
                k = draw(st.sampled_from(words))
                others = [parts[w] for w in words]
                parts[k] = draw(st.one_of(st.sampled_from(NASTY), st.sampled_from(others),
                                          st.floats(allow_nan=True, allow_infinity=True).map(repr)))
                text = "".join(parts)
        elif op == "insert":
            at = draw(st.integers(0, len(text)))
            text = text[:at] + draw(st.one_of(st.sampled_from(NASTY), st.text(max_size=12))) + text[at:]
        else:
            at = draw(st.integers(0, len(text)))
            text = text[:at] + text[at + draw(st.integers(1, 40)):]
    return text


def write(tmp: Path, name: str, text: str) -> Path:
    path = tmp / name
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    return path


def check_chain(chain: KinematicChain | None) -> None:
    if chain is None:
        return
    assert isinstance(chain, KinematicChain)
    assert chain.n_bones == chain.n_joints - 1
    if chain.rest_pose is not None:
        assert np.isfinite(chain.rest_pose).all()


# ------------------------------------------------------------------------------------------ descriptions
def test_seeds_are_valid(tmp_path):
    """The seeds load: a fuzz failure then means the edit broke something, not the seed."""
    from chainspace import from_asf, from_bvh, from_skeleton_file, from_urdf, load_amc, load_bvh
    from chainspace.io.tracks import load_tracks

    assert from_urdf(write(tmp_path, "s.urdf", URDF_SEED)).n_joints == 4
    chain = from_asf(write(tmp_path, "s.asf", ASF_SEED))
    assert chain.joints == ("root", "lfemur", "ltibia", "spine")
    assert load_amc(chain, write(tmp_path, "s.amc", AMC_SEED)).shape == (3, 4, 3)
    assert from_bvh(write(tmp_path, "s.bvh", BVH_SEED)).n_joints == 5
    assert load_bvh(write(tmp_path, "m.bvh", BVH_SEED))[1].shape == (3, 5, 3)
    assert from_skeleton_file(write(tmp_path, "s.toml", TOML_SEED)).n_joints == 4
    assert from_skeleton_file(write(tmp_path, "s.yaml", YAML_SEED)).rigid_links == (("b", "c"),)
    P, C, names = load_tracks(write(tmp_path, "s.csv", CSV_SEED))
    assert P.shape == (2, 4, 2) and names == ["root", "a", "b", "c"]
    P, C, names = load_tracks(write(tmp_path, "s.json", COCO_SEED))
    assert P.shape == (2, 17, 2)


@FUZZ
@given(text=mutated(URDF_SEED))
def test_fuzz_urdf(tmp_path, text):
    from chainspace import from_urdf

    check_chain(only_chainspace_errors(from_urdf, write(tmp_path, "f.urdf", text)))


@FUZZ
@given(text=mutated(ASF_SEED))
def test_fuzz_asf(tmp_path, text):
    from chainspace import from_asf

    check_chain(only_chainspace_errors(from_asf, write(tmp_path, "f.asf", text)))


@FUZZ
@given(text=mutated(AMC_SEED))
def test_fuzz_amc(tmp_path, text):
    from chainspace import from_asf, load_amc

    chain = from_asf(write(tmp_path, "s.asf", ASF_SEED))
    poses = only_chainspace_errors(load_amc, chain, write(tmp_path, "f.amc", text))
    if poses is not None:
        assert poses.ndim == 3 and poses.shape[1:] == (4, 3) and len(poses) >= 1
        assert np.isfinite(poses).all()


@FUZZ
@given(text=mutated(BVH_SEED))
def test_fuzz_bvh(tmp_path, text):
    from chainspace import load_bvh

    got = only_chainspace_errors(load_bvh, write(tmp_path, "f.bvh", text))
    if got is not None:
        chain, poses, fps = got
        check_chain(chain)
        assert poses.shape[1:] == (chain.n_joints, 3) and np.isfinite(poses).all()
        assert np.isfinite(fps) and fps > 0


@FUZZ
@given(text=mutated(TOML_SEED))
def test_fuzz_skeleton_toml(tmp_path, text):
    from chainspace import from_skeleton_file

    check_chain(only_chainspace_errors(from_skeleton_file, write(tmp_path, "f.toml", text)))


@FUZZ
@given(text=mutated(YAML_SEED))
def test_fuzz_skeleton_yaml(tmp_path, text):
    from chainspace import from_skeleton_file

    check_chain(only_chainspace_errors(from_skeleton_file, write(tmp_path, "f.yaml", text)))


ANY_YAML = st.recursive(
    st.none() | st.booleans() | st.integers(-3, 3) | st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from(["root", "a", "b", "c", "m", "cm", "z", "y", ""]),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.sampled_from(["name", "rest", "parent", "child", "x"]),
                                                               inner, max_size=3),
    max_leaves=10,
)


@FUZZ
@given(doc=st.fixed_dictionaries(
    {"joints": st.one_of(ANY_YAML, st.just([{"name": "root", "rest": [0, 0, 0]}, {"name": "a", "rest": [0, 0, 1]}]))},
    optional={k: ANY_YAML for k in ("name", "units", "up", "bones", "rigid_links", "description", "source")}))
def test_fuzz_skeleton_structure(tmp_path, doc):
    """Type confusion in a well-formed YAML skeleton file (lists for strings, numbers for names, ...)."""
    import yaml

    from chainspace import from_skeleton_file

    check_chain(only_chainspace_errors(from_skeleton_file, write(tmp_path, "s.yaml", yaml.safe_dump(doc))))


@FUZZ
@given(data=st.binary(max_size=300), ext=st.sampled_from([".urdf", ".asf", ".bvh", ".toml", ".yaml"]))
def test_fuzz_binary_garbage_through_load_chain(tmp_path, data, ext):
    from chainspace import load_chain

    path = tmp_path / f"g{ext}"
    path.write_bytes(data)
    check_chain(only_chainspace_errors(load_chain, path))


LINKS = ["base", "upper", "fore", "hand", "tip", "nope", ""]


@FUZZ
@given(links=st.one_of(st.none(), st.lists(st.sampled_from(LINKS), max_size=5), ANY_YAML),
       extra=st.one_of(st.none(), ANY_YAML, st.dictionaries(
           st.sampled_from(["tip", "hand", "", "x"]),
           st.tuples(st.sampled_from(LINKS), st.lists(st.floats(-1, 1) | st.sampled_from([np.nan, np.inf]),
                                                     min_size=2, max_size=4)), max_size=2)),
       q=st.one_of(st.none(), ANY_YAML, st.dictionaries(st.sampled_from(["shoulder", "elbow", "wrist", "nope"]),
                                                        st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=2),
                                                        max_size=3)))
def test_fuzz_urdf_options(tmp_path, links, extra, q):
    """from_urdf's links / extra_frames / q: any structure is a chain or a ChainspaceError."""
    from chainspace import from_urdf

    path = write(tmp_path, "arm.urdf", URDF_SEED)
    check_chain(only_chainspace_errors(from_urdf, path, links=links, extra_frames=extra, q=q))


# ------------------------------------------------------------------------------------------ track files
@FUZZ
@given(text=mutated(CSV_SEED))
def test_fuzz_tracks_csv(tmp_path, text):
    from chainspace.io.tracks import load_tracks

    got = only_chainspace_errors(load_tracks, write(tmp_path, "f.csv", text))
    if got is not None:
        P, C, names = got
        assert P.ndim == 3 and P.shape[1:] == (len(names), 2) and not np.isinf(P).any()
        assert C is None or (C.shape == P.shape[:2] and np.all((C >= 0) & (C <= 1)))


@FUZZ
@given(text=mutated(COCO_SEED))
def test_fuzz_tracks_coco_json(tmp_path, text):
    from chainspace.io.tracks import load_tracks

    got = only_chainspace_errors(load_tracks, write(tmp_path, "f.json", text))
    if got is not None:
        P, C, names = got
        assert P.shape[1:] == (len(names), 2) and not np.isinf(P).any()


# ------------------------------------------------------------------------------------------ reconstruct
def _small_chain() -> KinematicChain:
    """A 6-joint tree with a non-degenerate rest pose (metres)."""
    joints = ["root", "a", "b", "c", "d", "e"]
    bones = [("root", "a"), ("a", "b"), ("a", "c"), ("root", "d"), ("d", "e")]
    rest = [[0, 0, 0], [0, 0, 0.5], [0.3, 0, 0.6], [-0.3, 0.1, 0.6], [0.1, 0.1, -0.4], [0.1, -0.1, -0.8]]
    return KinematicChain(joints, bones, rest)


CHAIN = _small_chain()
# Garbage magnitudes (a detector's 1e300) must be refused by name; any unit from 1e-6 to 1e12 works.
SPECIAL = st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e8, -1e8, 1e300, -1e300, 1e-300, 5e-324])
SCALES = [1.0, 100.0, 1e-3, 1e4, 1e-6, 1e9]


@st.composite
def track_arrays(draw):
    """(F, J, 2) tracks: three in four usable (right shape, missing points, odd values), the rest
    anything (wrong shapes, inf, whole joints or frames missing)."""
    usable = draw(st.integers(0, 3)) > 0
    F = draw(st.integers(2, 10) if usable else st.integers(0, 8))
    J = CHAIN.n_joints if usable else draw(st.sampled_from([CHAIN.n_joints] * 3 + [0, 1, CHAIN.n_joints + 1]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    scale = draw(st.sampled_from(SCALES))
    W = rng.normal(size=(F, J, 2)) * scale + draw(st.floats(-1e4, 1e4))
    edits = ["nan_point", "nan_frame", "constant_joint", "equal_frame", "zero"]
    if not usable:
        edits += ["special", "nan_joint"]
    if F and J:
        for _ in range(draw(st.integers(0, 6))):
            f, j = draw(st.integers(0, F - 1)), draw(st.integers(0, J - 1))
            what = draw(st.sampled_from(edits))
            if what == "special":
                W[f, j, draw(st.integers(0, 1))] = draw(SPECIAL)
            elif what == "nan_point":
                W[f, j, draw(st.integers(0, 1))] = np.nan
            elif what == "zero":
                W[f, j] = 0.0
            elif what == "nan_frame":
                W[f] = np.nan
            elif what == "nan_joint":
                W[:, j] = np.nan
            elif what == "constant_joint":
                W[:, j] = W[0, j]
            else:
                W[f] = W[0]
    shape = "ok" if usable else draw(st.sampled_from(["ok", "2d", "4d", "3ch", "1ch"]))
    if shape == "2d":
        W = W.reshape(F * J, 2) if F * J else W[0] if F else np.zeros((0, 2))
    elif shape == "4d":
        W = W[None]
    elif shape == "3ch":
        W = np.concatenate([W, rng.uniform(-0.2, 1.2, size=W.shape[:2] + (1,))], axis=-1)
    elif shape == "1ch":
        W = W[..., :1]
    return W


@FUZZ
@given(W=track_arrays(), conf=st.sampled_from([None, None, "uniform", "nan", "out_of_range", "wrong_shape"]),
       method=st.sampled_from(["default", "kcs", "rigid"]), seed=st.integers(0, 1000))
def test_fuzz_reconstruct_tracks(W, conf, method, seed):
    from chainspace.reconstruction.pipeline import reconstruct

    rng = np.random.default_rng(seed)
    c = None
    if conf is not None and W.ndim == 3:
        F, J = W.shape[:2]
        c = {"uniform": lambda: rng.uniform(0, 1, (F, J)),
             "out_of_range": lambda: rng.uniform(-0.5, 1.5, (F, J)),
             "nan": lambda: np.where(rng.uniform(size=(F, J)) < 0.3, np.nan, 1.0),
             "wrong_shape": lambda: np.ones((F + 1, J))}[conf]()
    rec = only_chainspace_errors(reconstruct, W, CHAIN, method=method, confidence=c, max_iter=5)
    event("reconstructed" if rec is not None else "refused")
    if rec is not None:
        F = W.shape[0]
        assert rec.poses.shape == (F, CHAIN.n_joints, 3) and rec.cameras.shape == (F, 2, 3)
        assert np.isfinite(rec.poses).all(), "a reconstruction returned non-finite poses without an error"
        assert np.isfinite(rec.cameras).all()
        assert isinstance(rec.converged, bool) and rec.message


@FUZZ
@given(max_iter=st.one_of(st.none(), st.integers(1, 4)),
       tol=st.one_of(st.none(), st.floats(1e-12, 10.0)),
       n_basis=st.one_of(st.none(), st.integers(1, 15)),
       method=st.sampled_from(["default", "kcs"]))
def test_fuzz_reconstruct_valid_options(max_iter, tol, n_basis, method):
    """Any valid solver option gives a finite result (invalid ones: BUGS.md #1, in test_bad_inputs)."""
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.synthetic.views import observe, orbit_cameras, swing_motion

    X = swing_motion(CHAIN, 12, seed=1)
    W = observe(X, orbit_cameras(12, scale=200.0, sweep_deg=40, seed=2))
    rec = only_chainspace_errors(reconstruct, W, CHAIN, method=method, max_iter=max_iter, tol=tol,
                                 n_basis=n_basis)
    assert rec is not None, "valid options were refused"
    assert np.isfinite(rec.poses).all() and rec.n_iter <= (max_iter or 50)
