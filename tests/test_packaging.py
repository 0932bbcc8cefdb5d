"""The package builds an sdist and a wheel that carry the shipped descriptions and data, and the wheel
installs and imports in a fresh virtual environment.

What is checked, and how (about a minute; `python -m build` fetches setuptools into its isolated build
environment from the package index or pip's cache):

* the sdist holds README.md, LICENSE, CHANGELOG.md, CITATION.cff and pyproject.toml;
* the wheel holds the shipped descriptions (chainspace/robots/*.urdf, *.toml), the bundled CMU data
  with its PROVENANCE.md, the licence and the `chainspace` console script;
* a fresh venv (no system site-packages) takes the wheel with ``pip install --no-deps`` and imports
  ``chainspace`` and ``chainspace.robots`` and finds the shipped URDF as package data; the
  dependencies (numpy, Pinocchio, ...) are not installed there, to keep the test short;
* the same wheel unpacked into a folder on PYTHONPATH, with the test environment's dependencies,
  loads a shipped chain, reads the bundled CMU data and reconstructs, from outside the repository.
"""

import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(*args, **kwargs):
    result = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=600, **kwargs)
    assert result.returncode == 0, f"{args} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result.stdout


@pytest.mark.slow
def test_sdist_and_wheel_build_install_and_import(tmp_path):
    """One test, so that parallel workers (pytest-xdist) never build the package twice at once."""
    pytest.importorskip("build")
    dist = build(tmp_path / "dist")
    check_sdist(dist)
    check_wheel(dist)
    wheel_imports_in_a_fresh_venv(dist, tmp_path / "fresh")
    wheel_works_outside_the_repository(dist, tmp_path / "outside")


def build(out):
    run(sys.executable, "-m", "build", "--outdir", out, ROOT, cwd=ROOT)
    wheels, sdists = sorted(out.glob("chainspace-*.whl")), sorted(out.glob("chainspace-*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1, sorted(p.name for p in out.iterdir())
    return wheels[0], sdists[0]


def check_sdist(dist):
    _, sdist = dist
    with tarfile.open(sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    for name in ("README.md", "LICENSE", "CHANGELOG.md", "CITATION.cff", "pyproject.toml",
                 "robots/milling_arm.urdf", "chainspace/data/PROVENANCE.md"):
        assert name in names, f"{name} missing from {sdist.name}"


def check_wheel(dist):
    wheel, _ = dist
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in ("chainspace/__init__.py", "chainspace/robots/__init__.py", "chainspace/robots/milling_arm.urdf",
                 "chainspace/robots/human17.toml", "chainspace/robots/coco17.toml", "chainspace/robots/horse.toml",
                 "chainspace/robots/README.md", "chainspace/data/PROVENANCE.md", "chainspace/data/cmu/35.asf",
                 "chainspace/data/cmu/35_01.amc"):
        assert name in names, f"{name} missing from {wheel.name}"
    info = [n for n in names if ".dist-info/" in n]
    assert any(n.endswith("LICENSE") for n in info), "the wheel carries no LICENSE"
    entry_points = next(n for n in info if n.endswith("entry_points.txt"))
    assert "chainspace = chainspace.cli:app" in zipfile.ZipFile(wheel).read(entry_points).decode()


def wheel_imports_in_a_fresh_venv(dist, tmp_path):
    wheel, _ = dist
    tmp_path.mkdir()
    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", venv)
    python = venv / ("Scripts/python.exe" if sys.platform == "win32" else "bin/python")
    run(python, "-m", "pip", "install", "-q", "--no-deps", "--no-index", wheel)
    out = run(python, "-c",
              "import importlib.resources, chainspace, chainspace.robots; "
              "assert importlib.resources.files('chainspace.robots').joinpath('milling_arm.urdf').is_file(); "
              "assert importlib.resources.files('chainspace').joinpath('data/cmu/35.asf').is_file(); "
              "print(chainspace.__version__, chainspace.__file__)", cwd=tmp_path)
    version, location = out.split()
    assert version == __import__("chainspace").__version__
    assert Path(location).is_relative_to(venv), location


def wheel_works_outside_the_repository(dist, tmp_path):
    wheel, _ = dist
    tmp_path.mkdir()
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = (
        "import chainspace as cs, importlib.resources as r; "
        "assert cs.__file__.startswith(%r), cs.__file__; "
        "arm = cs.shipped('milling_arm'); "
        "walk = cs.load_amc(cs.from_asf(r.files('chainspace') / 'data/cmu/35.asf'), r.files('chainspace') / 'data/cmu/35_01.amc'); "
        "person = cs.shipped('human17'); "
        "rec = cs.reconstruct(cs.observe(cs.synthesize(arm, n_frames=20, seed=0).positions, "
        "cs.orbit_cameras(20, scale=300.0, seed=0)), arm); "
        "print(arm.n_joints, walk.shape[1], person.n_joints, rec.poses.shape)"
    ) % str(site)
    env = {"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    out = run(sys.executable, "-c", code, cwd=tmp_path, env=env)
    assert out.split()[:3] == ["9", "31", "17"], out
