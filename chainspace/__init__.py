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
    "CameraError": "errors",
    "VideoError": "errors",
    "OutputExistsError": "errors",
    "ConvergenceWarning": "errors",
    # the chain and its descriptions
    "KinematicChain": "chain",
    "from_urdf": "io.urdf",
    "from_asf": "io.asf",
    "load_amc": "io.asf",
    "from_bvh": "io.bvh",
    "load_bvh": "io.bvh",
    "save_bvh": "io.bvh",
    "from_skeleton_file": "io.skeleton_file",
    "save_skeleton_file": "io.skeleton_file",
    "load_chain": "io.descriptions",
    "shipped": "io.descriptions",
    "shipped_path": "io.descriptions",
    "list_shipped": "io.descriptions",
    "example_robot_urdf": "io.descriptions",
    "pinocchio_model": "io.urdf",
    "point_positions": "io.urdf",
    # 2D tracks in and out
    "load_tracks": "io.tracks",
    "save_tracks": "io.tracks",
    # reconstruction
    "reconstruct": "reconstruction.pipeline",
    "Reconstruction": "reconstruction.pipeline",
    "fit_cameras": "cameras.weak",
    "project": "cameras.weak",
    "PinholeCamera": "cameras.pinhole",
    "as_camera": "cameras.pinhole",
    # metrics and synthetic views
    "mpjpe": "metrics",
    "procrustes_align": "metrics",
    "error_3d": "metrics",
    "bone_length_stats": "metrics",
    "orbit_cameras": "synthetic.views",
    "observe": "synthetic.views",
    # robots
    "fit_joint_angles": "robot.fit",
    "JointFit": "robot.result",
    "synthesize": "synthetic.robot",
    "RobotTrial": "synthetic.robot",
    "validate": "robot.validation",
    "ValidationReport": "robot.validation",
    # results, views, plots
    "save_results": "io.results",
    "load_results": "io.results",
    "atomic_write": "io.results",
    "plot_convergence": "view.plots",
    "plot_joint_angles": "view.plots",
    "plot_joint_errors": "view.plots",
    "plot_error_sweep": "view.plots",
    "write_html": "view.viewer",
    "show": "view.viewer",
    "draw_overlay": "video.overlay",
    # video: reading frames, key frames, tracking points
    "open_video": "video.reader",
    "Video": "video.reader",
    "frame_writer": "video.writer",
    "load_keyframes": "video.keyframes",
    "track_points": "video.tracking",
    "track_video": "video.tracking",
    "TrackResult": "video.tracking",
    "write_picker": "video.picker",
    # many recordings at once, on Dask
    "run_batch": "batch",
    "read_manifest": "batch",
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
        CameraError,
        ChainspaceError,
        ConvergenceWarning,
        DescriptionError,
        DescriptionNotFoundError,
        OutputExistsError,
        TrackError,
        VideoError,
    )
