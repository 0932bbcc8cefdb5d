"""The documentation site builds without a warning, names the whole public API, and its tutorials
run as written (every ```python block of a page, in order, in one namespace, in a fresh folder)."""

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
TUTORIALS = sorted((DOCS / "tutorials").glob("*.md"))


def python_blocks(page: Path) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", page.read_text(encoding="utf-8"), re.S | re.M)


@pytest.mark.slow
def test_site_builds_without_warnings(tmp_path):
    sphinx_build = pytest.importorskip("sphinx.cmd.build")
    status = sphinx_build.build_main(
        ["-W", "--keep-going", "-E", "-a", "-q", "-b", "html", "-d", str(tmp_path / "doctrees"), str(DOCS),
         str(tmp_path / "html")]
    )
    assert status == 0, "sphinx-build reported warnings or errors (run `make docs`)"
    assert (tmp_path / "html" / "api.html").stat().st_size > 50_000


def test_api_page_names_every_public_name():
    import chainspace

    api = (DOCS / "api.rst").read_text(encoding="utf-8")
    documented = set(re.findall(r"^\.\. auto\w+:: chainspace\.(\w+)", api, re.M))
    assert documented == set(chainspace._EXPORTS), (
        f"missing from docs/api.rst: {sorted(set(chainspace._EXPORTS) - documented)}; "
        f"not public: {sorted(documented - set(chainspace._EXPORTS))}"
    )


def test_every_tutorial_is_in_the_index_and_has_code_or_says_why():
    index = (DOCS / "index.md").read_text(encoding="utf-8")
    for page in TUTORIALS:
        assert f"tutorials/{page.stem}" in index, f"{page.name} is not in the index's toctree"
        assert python_blocks(page) or "not available yet" in page.read_text(encoding="utf-8"), page.name


WRITERS = {"save_tracks", "save_results", "write_html", "draw_overlay", "render_trial", "render_video",
           "save_marker_tracks", "track_video", "save_bvh", "write_picker", "save"}


@pytest.mark.parametrize("page", [p for p in TUTORIALS if python_blocks(p)], ids=lambda p: p.stem)
def test_tutorials_can_be_run_again(page):
    """Every chainspace writer a tutorial calls is given overwrite=True: a second run in the same
    folder must not stop at the first file the first run wrote."""
    import ast

    for code in python_blocks(page):
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.Call) and isinstance(node.func, (ast.Attribute, ast.Name)):
                name = node.func.attr if isinstance(node.func, ast.Attribute) else node.func.id
                if name in WRITERS and not (name == "save" and ast.unparse(node.func).startswith("np.")):
                    assert any(k.arg == "overwrite" for k in node.keywords), f"{page.name}: {ast.unparse(node)}"


def test_the_batch_tutorial_runs_as_a_script_twice(tmp_path):
    """Saved as a file and run (Dask's workers import it again: the guard), then run again (a rerun
    overwrites its tracks and resumes the batch)."""
    import subprocess
    import sys

    pytest.importorskip("dask.distributed")
    (tmp_path / "batch_tutorial.py").write_text(python_blocks(DOCS / "tutorials" / "batch.md")[0], encoding="utf-8")
    for run in ("first", "again"):
        done = subprocess.run([sys.executable, "batch_tutorial.py"], cwd=tmp_path, capture_output=True, text=True,
                              timeout=600, env={**os.environ, "PYTHONPATH": str(ROOT)})
        assert done.returncode == 0, f"{run}: {done.stderr[-2000:]}"
        assert "3 ok" in done.stdout and "1 failed" in done.stdout


@pytest.mark.slow
@pytest.mark.parametrize("page", [p for p in TUTORIALS if python_blocks(p)], ids=lambda p: p.stem)
def test_tutorial_runs_as_written(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__main__"}  # as a saved script runs: its `if __name__ == "__main__":` blocks too
    for code in python_blocks(page):
        exec(compile(code, str(page), "exec"), namespace)


def test_format_examples_load():
    """Every example file on the file-format page is read by chainspace as the page says."""
    import numpy as np

    import chainspace as cs

    ex = DOCS / "formats" / "examples"
    page = (DOCS / "formats" / "index.md").read_text(encoding="utf-8")
    for path in ex.rglob("*"):
        if path.is_file():
            assert f"examples/{path.relative_to(ex).as_posix()}" in page or path.parent.name == "openpose", path
    chains = {name: cs.load_chain(ex / name) for name in
              ("two_link_arm.urdf", "quadruped.toml", "arm_and_hand.yaml", "pendulum.bvh", "leg.asf")}
    assert chains["quadruped.toml"].rigid_links == (("left_hind_paw", "right_hind_paw"),)
    np.testing.assert_allclose(chains["quadruped.toml"].rest_pose[0], [0, 0, 0.55])  # cm -> m
    np.testing.assert_allclose(chains["arm_and_hand.yaml"].rest_pose[1], [0, 0, -0.3])  # y up, mm -> z up, m
    assert cs.load_amc(chains["leg.asf"], ex / "leg.amc").shape == (2, 3, 3)
    assert cs.load_bvh(ex / "pendulum.bvh")[1].shape == (3, 4, 3)

    person = cs.shipped("coco17")
    coco, conf, _ = cs.load_tracks(ex / "keypoints_coco.json", chain=person)
    assert coco.shape == (2, 17, 2) and np.isnan(coco[1, 4]).all() and conf[1, 3] == 0.2
    for name in ("openpose", "landmarks_mediapipe.json"):
        tracks, _, _ = cs.load_tracks(ex / name, chain=person)
        np.testing.assert_allclose(tracks, coco, atol=0.06)  # the same two frames, written by save_tracks
    tracks, conf, names = cs.load_tracks(ex / "tracks.csv")
    assert tracks.shape == (2, 4, 2) and names == ["base_link", "link_1", "link_2", "link_3"]
