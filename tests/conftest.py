"""Shared test fixtures (keep small)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]

# Rendered clips (the demo's video) are cached in one folder that every test worker shares, so a clip
# that several tests film is rendered once; never the user's own cache.
os.environ.setdefault("CHAINSPACE_CACHE", str(Path(tempfile.gettempdir()) / "chainspace-test-cache"))


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
