"""ArUco marker maps (loader, errors naming the line), detection on rendered frames against the rendered
truth, and the chain the markers track."""

import numpy as np
import pytest

from chainspace.video.markers import (MarkerError, centre_of, detect_in_frame, load_marker_map, marker_chain,
                                      shipped_marker_map)


@pytest.fixture(scope="module")
def shipped(milling_arm_urdf):
    return load_marker_map(shipped_marker_map("milling_arm"), urdf=milling_arm_urdf)


def test_shipped_map_names_links_of_the_urdf(shipped):
    assert len(shipped) == 23 and shipped.ids == list(range(23))
    assert {m.link for m in shipped.markers} >= {"base_link", "link_2", "link_4", "spindle"}
    # the marker's z axis is its normal: a marker on the base's +x side faces +x
    m0 = shipped.markers[0]
    assert np.allclose(m0.rotation()[:, 2], [1, 0, 0], atol=1e-6)
    # corners of a marker lie on a square of its side
    c = m0.corners_in_link()
    assert np.allclose(np.linalg.norm(np.diff(c, axis=0, append=c[:1]), axis=1), m0.size)


@pytest.mark.parametrize("row, field", [
    ("3,link_2,0.1,0,0,,,,-0.2", "'size'"),
    ("3,link_2,0.1,zero,0,,,,0.2", "'y'"),
    ("x3,link_2,0.1,0,0,,,,0.2", "'id'"),
    ("0,link_2,0.1,0,0,,,,0.2", "already on line 2"),
    ("77,link_2,0.1,0,0,,,,0.2", "not in DICT_4X4_50"),
    ("3,link_9,0.1,0,0,,,,0.2", "'link' names 'link_9'"),
])
def test_bad_marker_map_names_the_line_and_field(tmp_path, milling_arm_urdf, row, field):
    path = tmp_path / "bad.csv"
    path.write_text("id,link,x,y,z,roll,pitch,yaw,size\n0,base_link,0.4,0,0.2,0,1.57,0,0.2\n" + row + "\n")
    with pytest.raises(MarkerError, match=rf"bad.csv:3: .*{field}"):
        load_marker_map(path, urdf=milling_arm_urdf)


def test_marker_map_without_a_column_is_refused(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("# a comment\nid,link,x,y,size\n0,base_link,0,0,0.2\n")
    with pytest.raises(MarkerError, match=r"m.csv:2: .*lacks column\(s\) z"):
        load_marker_map(path)


def test_centre_of_a_square_under_perspective_is_its_diagonals_crossing():
    from chainspace.cameras.pinhole import PinholeCamera

    cam = PinholeCamera(800, 800, 320, 240)
    a = np.deg2rad(50)  # a square turned 50 degrees away: its corners' mean misses the centre
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    sq = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * 0.2 @ R.T + [0.3, 0.1, 1.5]
    px = cam.project(sq)
    true = cam.project(np.array([0.3, 0.1, 1.5]))
    assert np.linalg.norm(centre_of(px) - true) < 1e-9
    assert np.linalg.norm(px.mean(0) - true) > 1.0


def test_marker_chain_hangs_markers_from_their_links(shipped, milling_arm_urdf):
    chain = marker_chain(milling_arm_urdf, shipped)
    assert chain.joints[0].startswith("marker_") and chain.parents[0] == -1
    assert set(chain.joints) == set(shipped.names)
    link = {m.name: m.link for m in shipped.markers}
    order = ["base_link", "link_1", "link_2", "link_3", "link_4", "spindle"]
    for parent, child in chain.bones:  # a marker hangs from one on its own link or above it
        assert order.index(link[parent]) <= order.index(link[child])
    sub = marker_chain(milling_arm_urdf, shipped, names=["marker_4", "marker_9", "marker_16"])
    assert sub.joints == ("marker_4", "marker_9", "marker_16")
    assert sub.metadata["extra_frames"]["marker_16"][0] == "spindle"


def test_markers_on_a_rendered_frame_are_found_to_half_a_pixel(shipped, milling_arm_urdf):
    """Every marker the renderer shows whole (facing the camera within 60 degrees, nothing in front of it
    or its white margin, inside the image) and at least 20 px across is found, its corners within 0.5 px
    of where the camera puts them."""
    pytest.importorskip("pybullet")
    from chainspace.synthetic.robot import synthesize
    from chainspace.video.render import RobotRenderer

    size = (1280, 960)
    trial = synthesize(milling_arm_urdf, n_frames=2, camera="pinhole", image_size=size, noise_px=0.0, seed=4,
                       trajectory="milling", distance_reaches=1.5, focal_px=1.2 * size[0])
    with RobotRenderer(trial.chain, trial.intrinsics, trial.camera_R, trial.camera_t, markers=shipped,
                       seed=0) as r:
        img, seg = r.render(trial.q[0])
        truth = r.truth(trial.q[:1])
        seen = r.visible(truth["marker_corners"][0], truth["marker_facing"][0], seg)
    corners = truth["marker_corners"][0]
    side = np.linalg.norm(np.diff(corners, axis=1), axis=-1).min(-1)
    big = seen & (side >= 20)
    assert big.sum() >= 3, "the view shows too few markers to test"
    found = detect_in_frame(img, shipped)
    err = np.linalg.norm(found - corners, axis=-1)
    assert np.isfinite(err[big]).all(), f"markers not found: {np.array(shipped.ids)[big & ~np.isfinite(err[:, 0])]}"
    assert err[big].max() < 0.5, np.round(err[big], 2)


def test_markers_command_writes_tracks_the_marker_chain_reads(tmp_path, milling_arm_urdf, shipped):
    """`chainspace markers` on a rendered clip writes a tracks CSV that load_tracks maps onto the marker
    chain; a file that is no video is a clear error (exit code 2)."""
    pytest.importorskip("pybullet")
    from typer.testing import CliRunner

    from chainspace import load_tracks
    from chainspace.cli import app
    from chainspace.synthetic.robot import synthesize
    from chainspace.video.render import render_trial

    trial = synthesize(milling_arm_urdf, n_frames=2, camera="pinhole", image_size=(640, 480), noise_px=0.0,
                       seed=8, trajectory="milling", distance_reaches=1.5)
    render_trial(trial, tmp_path / "clip.mp4", markers=shipped, seed=8)
    out = tmp_path / "tracks.csv"
    res = CliRunner().invoke(app, ["markers", str(tmp_path / "clip.mp4"), "--map", "milling_arm", "--out", str(out)])
    assert res.exit_code == 0, res.output
    names = sorted({line.split(",")[1] for line in out.read_text().splitlines()[1:]})
    assert len(names) >= 3 and all(n.startswith("marker_") for n in names)
    tracks, conf, _ = load_tracks(out, chain=marker_chain(milling_arm_urdf, shipped, names=names))
    assert tracks.shape == (2, len(names), 2) and (conf > 0).any(axis=0).all()
    assert (tmp_path / "tracks.corners.npz").is_file()
    # the tracks go on from the shell: --markers makes the chain of the markers the file names
    res = CliRunner().invoke(app, ["reconstruct", str(out), "--chain", "milling_arm", "--markers", "milling_arm",
                                   "--out", str(tmp_path / "rec")])
    assert res.exit_code in (0, 1), res.output  # 1: two frames may not converge; the chain is what is checked
    from chainspace import load_results

    assert sorted(load_results(tmp_path / "rec" / "reconstruction.npz").chain.joints) == names
    res = CliRunner().invoke(app, ["reconstruct", str(out), "--chain", "coco17", "--markers", "milling_arm",
                                   "--out", str(tmp_path / "rec2")])
    assert res.exit_code == 2 and "--markers needs a URDF chain" in res.output
    bad = tmp_path / "not_a_video.mp4"
    bad.write_text("hello")
    res = CliRunner().invoke(app, ["markers", str(bad), "--map", "milling_arm", "--out", str(tmp_path / "t2.csv")])
    assert res.exit_code == 2 and "not a video" in res.output


def test_ur10_map_hangs_base_markers_from_the_merged_root(example_urdf):
    """The UR10's base_link is welded to world (one point of its chain): markers on it are the root."""
    urdf = example_urdf("ur10")
    mmap = load_marker_map(shipped_marker_map("ur10"), urdf=urdf)
    on = {m.name: m.link for m in mmap.markers}
    assert sum(link == "wrist_3_link" for link in on.values()) >= 4  # the wrist needs two points on the last link
    chain = marker_chain(urdf, mmap, names=["marker_0", "marker_5", "marker_30", "marker_26"])
    assert chain.joints[0] == "marker_0" and on["marker_0"] == "base_link"
    assert set(chain.bones) == {("marker_0", "marker_5"), ("marker_5", "marker_26"), ("marker_26", "marker_30")}
