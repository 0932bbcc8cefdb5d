"""chainspace: monocular 3D motion of kinematic chains in the Kinematic Chain Space.

2D tracks of a human, an animal or a robot arm seen by one uncalibrated camera go in; 3D joint
positions, cameras and, for robots, joint angles checked against the robot's description come out.
The method is Wandt, Ackermann and Rosenhahn, "A Kinematic Chain Space for Monocular Motion
Capture" (2017), extended by a refinement stage that recovers depth.

The public API is re-exported here. Submodules load on first use, so ``import chainspace`` stays fast
and Pinocchio or meshcat are imported only by the functions that need them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# public name -> submodule that defines it
_EXPORTS: dict[str, str] = {
    # errors
    "ChainspaceError": "errors",
    "DescriptionError": "errors",
    "DescriptionNotFoundError": "errors",
    "TrackError": "errors",
    "OutputExistsError": "errors",
    "ConvergenceWarning": "errors",
    # the chain and its descriptions
    "KinematicChain": "chain",
    "from_urdf": "urdf",
    "from_asf": "asf",
    "load_amc": "asf",
    "from_bvh": "bvh",
    "load_bvh": "bvh",
    "save_bvh": "bvh",
    "from_skeleton_file": "skeleton_file",
    "save_skeleton_file": "skeleton_file",
    "load_chain": "descriptions",
    "shipped": "descriptions",
    "shipped_path": "descriptions",
    "list_shipped": "descriptions",
    "example_robot_urdf": "descriptions",
    "pinocchio_model": "urdf",
    "point_positions": "urdf",
    # 2D tracks in and out
    "load_tracks": "tracks",
    "save_tracks": "tracks",
    # reconstruction
    "reconstruct": "reconstruction",
    "Reconstruction": "reconstruction",
    "fit_cameras": "camera",
    "project": "camera",
    # metrics and synthetic views
    "mpjpe": "metrics",
    "procrustes_align": "metrics",
    "error_3d": "metrics",
    "bone_length_stats": "metrics",
    "orbit_cameras": "synthetic",
    "observe": "synthetic",
    # robots
    "fit_joint_angles": "fit",
    "JointFit": "fit",
    "synthesize": "robot_synthetic",
    "RobotTrial": "robot_synthetic",
    "validate": "validation",
    "ValidationReport": "validation",
    # results, views, plots
    "save_results": "results",
    "load_results": "results",
    "atomic_write": "results",
    "plot_convergence": "plots",
    "plot_joint_angles": "plots",
    "plot_joint_errors": "plots",
    "plot_error_sweep": "plots",
    "write_html": "viewer",
    "show": "viewer",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'chainspace' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__


if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .chain import KinematicChain
    from .errors import (
        ChainspaceError,
        ConvergenceWarning,
        DescriptionError,
        DescriptionNotFoundError,
        OutputExistsError,
        TrackError,
    )
