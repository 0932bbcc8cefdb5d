"""Shared test fixtures (keep small)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: tests are deterministic."""
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def milling_arm_urdf() -> Path:
    """The shipped milling-arm URDF."""
    from chainspace.io.descriptions import shipped_path

    return shipped_path("milling_arm")


@pytest.fixture(scope="session")
def example_urdf():
    """``example_urdf(name)`` -> Path of an example-robot-data URDF, or skip the test cleanly."""
    from chainspace.errors import ChainspaceError

    def find(name: str) -> Path:
        from chainspace.io.descriptions import example_robot_urdf

        try:
            return example_robot_urdf(name)
        except ChainspaceError as exc:
            pytest.skip(str(exc))

    return find


# Modules whose tests fit robots or build the package, a minute or more each on the 2-core CI machine.
_LONG_MODULES = {"test_fit.py", "test_fit_pinhole.py", "test_docs.py", "test_browser.py", "test_demo.py",
                 "test_readme.py", "test_packaging.py", "test_robot_joints.py"}


def pytest_collection_modifyitems(items):
    """Long tests first: pytest-xdist hands tests out in this order, so the workers then finish together
    instead of one of them running the longest robot fits alone at the end."""
    items.sort(key=lambda item: not (item.get_closest_marker("slow") or item.path.name in _LONG_MODULES))
