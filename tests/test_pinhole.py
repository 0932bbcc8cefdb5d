"""PinholeCamera: every way to make one projects like cv2.projectPoints; files round-trip; undistort,
the Jacobian and the errors."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import chainspace
from chainspace import CameraError, ChainspaceError, PinholeCamera, as_camera
from chainspace.errors import DescriptionNotFoundError, OutputExistsError

DATA = Path(__file__).parent / "data" / "cameras"
K = np.array([[800.5, 0.0, 319.5], [0.0, 802.25, 241.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.21, 0.08, 0.0012, -0.0007, -0.015])
FILES = ["opencv_calibration.yml", "opencv_calibration.xml", "opencv_kd.yaml", "camera.json", "camera_fx.json",
         "ros_camera_info.yaml", "ros_camera_info_msg.yaml", "ros1_camera_info_msg.yaml"]


def _points(n=200, seed=0):
    """Points in front of the camera that land inside (or near) a 640x480 image."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.0, 6.0, n)
    xy = rng.uniform([-0.45, -0.33], [0.45, 0.33], (n, 2)) * z[:, None]
    return np.column_stack([xy, z])


def _cv_project(K, dist, P):
    uv, _ = cv2.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(dist, float))
    return uv.reshape(-1, 2)


def _check_projects_like_opencv(cam):
    P = _points()
    np.testing.assert_allclose(cam.project(P), _cv_project(cam.K, cam.dist, P), atol=1e-6, rtol=0)


# ------------------------------------------------------------------------------------ construction
@pytest.mark.parametrize("dist", [None, DIST])
def test_from_matrix_projects_like_opencv(dist):
    cam = PinholeCamera.from_matrix(K, dist, 640, 480)
    np.testing.assert_array_equal(cam.K, K)
    assert cam.has_distortion == (dist is not None)
    assert cam.image_size == (640, 480)
    _check_projects_like_opencv(cam)


def test_from_fov_has_the_asked_field_of_view_and_centre():
    cam = PinholeCamera.from_fov(1920, 1080, 60.0)
    assert cam.fov_deg[0] == pytest.approx(60.0, abs=1e-9)
    assert (cam.cx, cam.cy) == (959.5, 539.5)
    assert cam.fx == cam.fy == pytest.approx(960 / math.tan(math.radians(30)))
    assert PinholeCamera.from_fov(1920, 1080, 40.0, axis="vertical").fov_deg[1] == pytest.approx(40.0)
    diag = PinholeCamera.from_fov(1920, 1080, 70.0, axis="diagonal")
    assert 2 * math.degrees(math.atan(math.hypot(960, 540) / diag.fx)) == pytest.approx(70.0)
    _check_projects_like_opencv(cam)


def test_from_focal_mm():
    # a 36 mm wide sensor behind a 50 mm lens, 6000 px across: 50 / 36 * 6000 px
    cam = PinholeCamera.from_focal_mm(50.0, 36.0, 6000, 4000)
    assert cam.fx == cam.fy == pytest.approx(50.0 / 36.0 * 6000)
    assert cam.fov_deg[0] == pytest.approx(2 * math.degrees(math.atan(18 / 50)))
    _check_projects_like_opencv(cam)


@pytest.mark.parametrize("name", FILES)
def test_every_file_format_loads_the_same_camera(name):
    cam = PinholeCamera.load(DATA / name)
    np.testing.assert_allclose(cam.K, K, rtol=1e-15)
    np.testing.assert_allclose(cam.dist, DIST, rtol=1e-15)
    assert cam.image_size == (640, 480)
    _check_projects_like_opencv(cam)
    assert as_camera(DATA / name) == cam and as_camera(str(DATA / name)) == cam


def test_a_real_calibrate_camera_output_loads_and_projects_like_opencv(tmp_path):
    # a 9x6 board seen from a few poses through a distorting lens, calibrated by OpenCV itself
    board = np.zeros((54, 3), np.float32)
    board[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.025
    rng = np.random.default_rng(3)
    objs, imgs = [], []
    for _ in range(8):
        rvec = rng.normal(scale=0.25, size=3)
        tvec = np.array([-0.1, -0.06, 0.5]) + rng.normal(scale=0.03, size=3)
        imgs.append(cv2.projectPoints(board, rvec, tvec, K, DIST)[0].astype(np.float32))
        objs.append(board)
    rms, K_cal, dist_cal, _, _ = cv2.calibrateCamera(objs, imgs, (640, 480), None, None)
    path = tmp_path / "calib.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)  # as OpenCV's calibration sample writes it
    fs.write("calibration_time", "now")
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K_cal)
    fs.write("distortion_coefficients", dist_cal)
    fs.write("avg_reprojection_error", rms)
    fs.release()
    cam = PinholeCamera.load(path)
    np.testing.assert_array_equal(cam.K, K_cal)
    np.testing.assert_array_equal(cam.dist, dist_cal.ravel()[:5])
    _check_projects_like_opencv(cam)


@pytest.mark.parametrize("suffix", [".yml", ".yaml", ".xml", ".json"])
def test_save_round_trips_and_opencv_reads_it(tmp_path, suffix):
    cam = PinholeCamera.from_matrix(K, DIST, 640, 480)
    path = cam.save(tmp_path / f"cam{suffix}")
    assert PinholeCamera.load(path) == cam
    if suffix != ".json":
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), K)
        np.testing.assert_array_equal(fs.getNode("distortion_coefficients").mat().ravel(), DIST)
        assert int(fs.getNode("image_width").real()) == 640
        fs.release()
    else:
        assert json.loads(path.read_text())["K"] == K.tolist()
    with pytest.raises(OutputExistsError):
        cam.save(path)
    PinholeCamera.from_fov(100, 50, 50.0).save(path, overwrite=True)
    assert PinholeCamera.load(path).image_size == (100, 50)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]


def test_save_without_size_round_trips(tmp_path):
    cam = PinholeCamera(500.0, 500.0, 100.0, 80.0)
    for suffix in (".yml", ".xml", ".json"):
        assert PinholeCamera.load(cam.save(tmp_path / f"c{suffix}")) == cam


# ------------------------------------------------------------------------------------ geometry
def test_project_gives_nan_behind_the_camera_and_for_nan_points():
    cam = PinholeCamera.from_matrix(K, DIST)
    P = np.array([[0.1, 0.2, 2.0], [0.1, 0.2, 0.0], [0.1, 0.2, -1.0], [np.nan, 0.0, 1.0]])
    uv = cam.project(P)
    assert np.isfinite(uv[0]).all() and np.isnan(uv[1:]).all()
    # frames-first batches keep their shape
    assert cam.project(np.broadcast_to(P, (7, 4, 3))).shape == (7, 4, 2)


def test_jacobian_matches_finite_differences():
    cam = PinholeCamera.from_matrix(K, DIST)
    P = _points(50, seed=4).reshape(5, 10, 3)
    uv, J = cam.project_with_jacobian(P)
    np.testing.assert_array_equal(uv, cam.project(P))
    assert J.shape == (5, 10, 2, 3)
    h = 1e-6
    fd = np.stack([(cam.project(P + h * e) - cam.project(P - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-5)
    _, Jbad = cam.project_with_jacobian(np.array([[0.0, 0.0, -1.0]]))
    assert np.isnan(Jbad).all()


@pytest.mark.parametrize("dist", [DIST, [-0.45, 0.25, 0.002, 0.001, -0.08]])  # typical, and a strong barrel
def test_undistort_inverts_the_distortion_inside_the_image(dist):
    cam = PinholeCamera.from_matrix(K, dist, 640, 480)
    P = _points(400, seed=5)
    uv = cam.project(P)
    inside = (uv >= -0.5).all(1) & (uv[:, 0] <= 639.5) & (uv[:, 1] <= 479.5)
    assert inside.sum() > 300
    ideal = PinholeCamera.from_matrix(K).project(P)
    batch = uv[inside].reshape(-1, 1, 2)[: 300].reshape(30, 10, 2)  # frames-first
    batch[3, 4] = np.nan
    out = cam.undistort(batch)
    assert out.shape == batch.shape
    assert np.isnan(out[3, 4]).all()
    expected = ideal[inside][:300].reshape(30, 10, 2)
    err = np.linalg.norm(out - expected, axis=-1)
    err[3, 4] = 0.0
    assert err.max() < 1e-3
    # rays are the normalised coordinates x/z, y/z
    rays = cam.rays(uv[inside])
    np.testing.assert_allclose(rays, P[inside, :2] / P[inside, 2:], atol=1e-6)
    # undistort agrees with OpenCV's own undistortion run to convergence
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    iterate = getattr(cv2, "undistortPointsIter", None)
    src = uv[inside].reshape(-1, 1, 2)
    cv = (iterate(src, cam.K, cam.dist, None, cam.K, criteria) if iterate is not None else
          cv2.undistortPoints(src, cam.K, cam.dist, P=cam.K, criteria=criteria)).reshape(-1, 2)
    np.testing.assert_allclose(cam.undistort(uv[inside]), cv, atol=1e-3)


def test_without_distortion_undistort_is_the_identity():
    cam = PinholeCamera.from_fov(640, 480, 60.0)
    uv = np.array([[10.0, 20.0], [np.nan, np.nan]])
    np.testing.assert_array_equal(cam.undistort(uv), uv)


def test_scaled_matches_resized_projection():
    cam = PinholeCamera.from_matrix(K, DIST, 640, 480)
    half = cam.scaled(0.5)
    assert half.image_size == (320, 240)
    P = _points()
    np.testing.assert_allclose(half.project(P), (cam.project(P) + 0.5) * 0.5 - 0.5, atol=1e-9)
    np.testing.assert_allclose(half.fov_deg, cam.fov_deg)


def test_camera_is_an_immutable_value():
    cam = PinholeCamera.from_matrix(K, DIST, 640, 480)
    with pytest.raises(Exception):
        cam.fx = 1.0
    with pytest.raises(ValueError):
        cam.dist[0] = 1.0
    assert cam == PinholeCamera.from_matrix(K.tolist(), list(DIST), 640, 480)
    assert len({cam, PinholeCamera.from_matrix(K, DIST, 640, 480)}) == 1
    assert "fx=800.5" in repr(cam)
    assert PinholeCamera(500.0, 500.0, 1.0, 1.0, None) == PinholeCamera(500.0, 500.0, 1.0, 1.0, [])


def test_as_camera():
    assert as_camera(None) is None
    cam = PinholeCamera.from_matrix(K)
    assert as_camera(cam) is cam
    assert as_camera(K) == cam and as_camera(K.tolist()) == cam
    assert as_camera(K, image_size=(640, 480)).image_size == (640, 480)
    sized = PinholeCamera.from_matrix(K, None, 640, 480)
    assert as_camera(sized, (640, 480)) is sized
    with pytest.raises(CameraError, match="640x480.*1280x960.*scaled"):
        as_camera(sized, (1280, 960))
    with pytest.raises(CameraError, match="intrinsics must be"):
        as_camera(3.5)
    assert chainspace.cameras.PinholeCamera is PinholeCamera


# ------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("kwargs, match", [
    (dict(fx=0.0, fy=500.0, cx=1.0, cy=1.0), "positive"),
    (dict(fx=500.0, fy=-1.0, cx=1.0, cy=1.0), "positive"),
    (dict(fx=np.nan, fy=500.0, cx=1.0, cy=1.0), "fx must be a finite"),
    (dict(fx=500.0, fy=500.0, cx=np.inf, cy=1.0), "cx must be a finite"),
    (dict(fx=500.0, fy=500.0, cx=1.0, cy=1.0, dist=[0.1, 0.2, 0.3]), "3 distortion coefficients"),
    (dict(fx=500.0, fy=500.0, cx=1.0, cy=1.0, dist=[0.1, np.nan, 0, 0, 0]), "finite"),
    (dict(fx=500.0, fy=500.0, cx=1.0, cy=1.0, width=640), "height is missing"),
    (dict(fx=500.0, fy=500.0, cx=1.0, cy=1.0, width=640.5, height=480), "whole number"),
])
def test_bad_values_are_clear_errors(kwargs, match):
    with pytest.raises(CameraError, match=match):
        PinholeCamera(**kwargs)


def test_bad_matrices_and_options():
    with pytest.raises(CameraError, match="shape"):
        PinholeCamera.from_matrix(np.eye(2))
    with pytest.raises(CameraError, match="skew"):
        PinholeCamera.from_matrix([[500, 3, 10], [0, 500, 10], [0, 0, 1]])
    with pytest.raises(CameraError, match="last row"):
        PinholeCamera.from_matrix([[500, 0, 10], [0, 500, 10], [1, 0, 1]])
    with pytest.raises(CameraError, match="non-finite"):
        PinholeCamera.from_matrix([[np.inf, 0, 10], [0, 500, 10], [0, 0, 1]])
    with pytest.raises(CameraError, match="positive"):
        PinholeCamera.from_matrix([[0, 0, 10], [0, 500, 10], [0, 0, 1]])
    for fov in (0.0, 180.0, -5.0, np.nan, "60"):
        with pytest.raises(CameraError, match="field of view"):
            PinholeCamera.from_fov(640, 480, fov)
    with pytest.raises(CameraError, match="axis"):
        PinholeCamera.from_fov(640, 480, 60.0, axis="width")
    with pytest.raises(CameraError, match="focal_mm"):
        PinholeCamera.from_focal_mm(0.0, 36.0, 640, 480)
    with pytest.raises(CameraError, match="scale factor"):
        PinholeCamera.from_fov(640, 480, 60.0).scaled(0)
    with pytest.raises(CameraError, match=r"\(\.\.\., 3\)"):
        PinholeCamera.from_fov(640, 480, 60.0).project(np.zeros((4, 2)))
    assert issubclass(CameraError, ChainspaceError) and issubclass(CameraError, ValueError)


@pytest.mark.parametrize("name, text, match", [
    ("nokey.json", '{"dist": [0, 0, 0, 0, 0], "width": 640, "height": 480}', r"nokey\.json.*no camera matrix.*fx"),
    ("partial.json", '{"fx": 500, "cx": 1}', r"partial\.json.*missing cy"),
    ("broken.json", '{"K": [[1, 0, 0]', r"broken\.json:1: not valid JSON"),
    ("shape.json", '{"K": [[1, 0], [0, 1]]}', r"shape\.json.*'K' has shape \(2, 2\)"),
    ("zero.json", '{"K": [[0, 0, 1], [0, 500, 1], [0, 0, 1]]}', r"zero\.json.*positive"),
    ("text.json", '{"K": "eye"}', r"text\.json.*not a numeric"),
    ("fisheye.yaml", "distortion_model: equidistant\nK: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n", r"fisheye\.yaml.*equidistant"),
    ("list.yaml", "- 1\n- 2\n", r"list\.yaml.*mapping"),
    ("bad.yaml", "K: [1, 2\nD: ]\n", r"bad\.yaml:\d+: not valid YAML"),
    ("ros.yaml", "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 2]\n", r"ros\.yaml.*rows x cols"),
    ("cv.yml", "%YAML:1.0\n---\nimage_width: 640\n", r"cv\.yml.*no camera matrix"),
    ("cv.xml", "<?xml version=\"1.0\"?>\n<opencv_storage>\n<camera_matrix>", r"cv\.xml:\d+: not a readable OpenCV"),
    ("calib.txt", "fx 500", r"calib\.txt.*unknown calibration format"),
])
def test_bad_files_name_the_file_and_the_problem(tmp_path, name, text, match):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(CameraError, match=match):
        PinholeCamera.load(path)


def test_a_yaml_flow_mapping_is_yaml_not_json(tmp_path):
    path = tmp_path / "flow.yaml"
    path.write_text("{K: [800, 0, 320, 0, 800, 240, 0, 0, 1], width: 640, height: 480}\n")
    assert PinholeCamera.load(path) == PinholeCamera(800.0, 800.0, 320.0, 240.0, width=640, height=480)


def test_missing_file():
    with pytest.raises(DescriptionNotFoundError, match="nowhere.yml"):
        PinholeCamera.load("nowhere.yml")
    with pytest.raises(ChainspaceError, match="nowhere.yml"):
        as_camera(Path("nowhere.yml"))


_scalars = (st.none() | st.booleans() | st.integers(-5, 2000) | st.floats(allow_nan=False, allow_infinity=False)
            | st.text(max_size=5))
_json_values = st.recursive(
    _scalars,
    lambda inner: st.lists(inner, max_size=10)
    | st.dictionaries(st.sampled_from(["rows", "cols", "data", "x"]), inner, max_size=4),
    max_leaves=20)
_keys = st.sampled_from(["K", "camera_matrix", "k", "dist", "D", "distortion_coefficients", "width", "height",
                         "image_width", "image_height", "image_size", "fx", "fy", "cx", "cy", "distortion_model"])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.dictionaries(_keys, _json_values, max_size=7), yaml_form=st.booleans())
def test_any_json_or_yaml_content_loads_or_is_a_chainspace_error(tmp_path, data, yaml_form):
    import yaml

    path = tmp_path / ("c.yaml" if yaml_form else "c.json")
    path.write_text(yaml.safe_dump(data) if yaml_form else json.dumps(data))
    try:
        cam = PinholeCamera.load(path)
    except ChainspaceError as exc:
        assert str(path) in str(exc)
    else:
        assert cam.fx > 0 and cam.fy > 0 and cam.dist.shape == (5,)
