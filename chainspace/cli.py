"""The ``chainspace`` command.

Exit codes, for scripts: 0 success; 1 the work ran but its result is not good (a reconstruction or fit
that did not converge, a validation that failed); 2 bad usage or bad input (the message says what and
where, on one line of stderr, without a traceback); 3 an unexpected internal error (a bug: one line naming the
exception; please report it). Every command that writes refuses to replace an
existing file unless given ``--overwrite``, never replaces one of its own inputs, and writes each file
atomically.
"""

from __future__ import annotations

import functools
import sys
import time
import warnings
from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
import typer

from .errors import ChainspaceError, TrackError

__all__ = ["app", "main"]

app = typer.Typer(
    name="chainspace",
    help="3D motion of kinematic chains (humans, animals, robot arms) from 2D tracks of one uncalibrated "
         "camera, and robot joint angles fitted and validated against the URDF.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"]},
)

EXIT_OK, EXIT_NOT_GOOD, EXIT_BAD_INPUT = 0, 1, 2
EXIT_INTERNAL = 3  # an unexpected exception: a bug, never "not converged"


def _console() -> Any:
    from rich.console import Console

    return Console(stderr=True, highlight=False)


def _fail(message: str, code: int) -> typer.Exit:
    _console().print(f"chainspace: error: {message}", markup=False, soft_wrap=True)
    return typer.Exit(code)


def _guarded(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn chainspace's errors into one line on stderr and exit code 2, and warnings into one line."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            with warnings.catch_warnings():
                warnings.showwarning = _show_warning
                return func(*args, **kwargs)
        except ChainspaceError as exc:
            raise _fail(_for_the_shell(str(exc)), EXIT_BAD_INPUT) from None
        except (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError) as exc:
            raise _fail(f"{exc.filename or ''}: {exc.strerror or exc}", EXIT_BAD_INPUT) from None
        except Exception as exc:  # a bug: say so on one line, with a code of its own (never 1)
            if isinstance(exc, (typer.Exit, typer.Abort)) or type(exc).__module__.split(".")[0] in (
                    "click", "typer"):
                raise  # the command's own exits and usage errors
            text = " ".join(str(exc).split()) or "(no message)"
            raise _fail(f"internal error: {type(exc).__name__}: {text} (this is a bug in chainspace; "
                        "please report it with the command line)", EXIT_INTERNAL) from None

    return wrapper


def _show_warning(message: Any, category: Any, *args: Any, **kwargs: Any) -> None:
    _console().print(f"chainspace: warning: {_for_the_shell(str(message))}", markup=False, soft_wrap=True)


# Advice that the library gives to Python callers, as a shell user would follow it.
_SHELL_ADVICE = (
    ("pass overwrite=True (--overwrite) to replace it", "use --overwrite to replace it"),
    ("pass overwrite=True to replace it", "use --overwrite to replace it"),
    ("pass overwrite=True", "use --overwrite"),
    ("drop it with chain.subset(...) or provide its track",
     "leave it out with --link (name every point to keep) or give its track"),
    ("drop them with chain.subset(...) or provide their tracks",
     "leave them out with --link (name every point to keep) or give their tracks"),
    ("pass urdf=PATH or a chain made by chainspace.from_urdf", "give --urdf"),
    ("pass urdf=PATH", "give --urdf"),
    ("pass format= one of", "give --format, one of"),
    ("pass init_pose (J, 3)", "give --init-pose (J, 3)"),
    ("pass intrinsics= (a calibration), image_size=(width, height) or perspective=True",
     "give --intrinsics FILE (a calibration), --image-size W H or --perspective"),
    ("(extra_frames)", "(--extra-frame)"),
    ("(links=, chain.subset)", "by --link"),
    ("links= '", "--link '"),
    ("in links=", "in --link"),
    ("an extra frame: extra_frames=)", "an extra frame: --extra-frame NAME=LINK:x,y,z)"),
    ("(fit.alternatives)", "(alternatives in joint_angles.npz; drawn grey in the joint plots)"),
    ("(RMS over the frames, fit.q_std)", "(RMS over the frames; per frame: q_std in joint_angles.npz)"),
    ("the camera-side rule (view_from)", "the camera-side rule (--view-from)"),
)


def _for_the_shell(message: str) -> str:
    """A library message with its Python advice (``pass overwrite=True``) in the command line's words."""
    for python, shell in _SHELL_ADVICE:
        message = message.replace(python, shell)
    return message


def _version_callback(value: bool) -> None:
    if value:
        from . import __version__

        typer.echo(f"chainspace {__version__}")
        raise typer.Exit(EXIT_OK)


@app.callback()
def _main(
    version: Annotated[bool, typer.Option("--version", callback=_version_callback, is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """3D motion of kinematic chains from 2D tracks of one uncalibrated camera."""


def _positive(option: str, value: float | None) -> None:
    """A numeric option must be a finite number > 0 (exit 2 otherwise, one line naming the option)."""
    from .errors import is_real

    if value is not None and not (is_real(value) and value > 0):
        raise TrackError(f"{option} must be a finite number > 0, not {value}")


def _seed(value: int) -> None:
    """A random seed is an integer >= 0 (numpy's rule), else exit 2 naming --seed."""
    if value < 0:
        raise TrackError(f"--seed must be an integer >= 0, not {value}")


def _parse_extra_frames(specs: list[str] | None) -> dict[str, tuple[str, list[float]]] | None:
    """``NAME=LINK:x,y,z`` (metres, in LINK's frame) -> ``{NAME: (LINK, [x, y, z])}`` for from_urdf."""
    if not specs:
        return None
    from .errors import DescriptionError

    out: dict[str, tuple[str, list[float]]] = {}
    for spec in specs:
        name, eq, rest = spec.partition("=")
        link, colon, xyz = rest.rpartition(":")
        try:
            values = [float(v) for v in xyz.split(",")]
        except ValueError:
            values = []
        if not (eq and colon and name.strip() and link.strip() and len(values) == 3
                and all(np.isfinite(values))):
            raise DescriptionError(f"--extra-frame {spec!r}: expected NAME=LINK:x,y,z (metres in LINK's "
                                   "frame), e.g. tool=flange:0,0,0.1")
        if name.strip() in out:
            raise DescriptionError(f"--extra-frame {name.strip()!r} is given twice")
        out[name.strip()] = (link.strip(), values)
    return out


ExtraFrames = Annotated[Optional[list[str]], typer.Option(
    "--extra-frame", metavar="NAME=LINK:x,y,z",
    help="A tracked point fixed to a URDF link, offset in that link's frame in metres (a tool tip; "
         "the way to make the first joint or a planar tool observable). Repeatable.")]

Links = Annotated[Optional[list[str]], typer.Option(
    "--link", metavar="NAME",
    help="Track only these points of the chain, in this order (a URDF's links or extra frames, a skeleton's "
         "joints); each hangs from its nearest kept ancestor. Repeatable.")]


def _status(message: str) -> Any:
    """A spinner on stderr while long work runs (silent when stderr is not a terminal)."""
    return _console().status(message, spinner="dots")


def _say(message: str) -> None:
    _console().print(message, markup=False, soft_wrap=True)


def _count(n: int, noun: str) -> str:
    """``1 recording``, ``2 recordings``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


# ---------------------------------------------------------------------------------------- inputs
def _load_array(path: Path, what: str, keys: tuple[str, ...] = ()) -> np.ndarray:
    """An array from .npy, .npz (first of ``keys`` present) or .csv (header row, first column frame)."""
    if not path.exists():
        raise TrackError(f"{path}: no such {what} file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            return np.load(path, allow_pickle=False)
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                for k in keys:
                    if k in z.files:
                        return z[k]
                raise TrackError(f"{path}: none of {', '.join(keys)} in the archive (found {', '.join(z.files)})")
        if suffix == ".csv":
            data = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float)
            return np.atleast_2d(data)[:, 1:]
    except (OSError, ValueError, EOFError) as exc:
        raise TrackError(f"{path}: cannot read the {what}: {exc}") from None
    raise TrackError(f"{path}: {what} must be .npy, .npz or .csv")


def _load_poses(path: Path | None, chain: Any) -> np.ndarray | None:
    if path is None:
        return None
    X = np.asarray(_load_array(path, "poses", ("poses", "positions", "truth")), dtype=float)
    if X.ndim != 3 or X.shape[1:] != (chain.n_joints, 3):
        raise TrackError(f"{path}: poses have shape {X.shape}, expected (frames, {chain.n_joints}, 3)")
    return X


def _load_q(path: Path, names: list[str], nq: int | None = None) -> np.ndarray:
    """Joint angles (F, len(names)) for joints ``names`` (one per joint), or (F, nq) in Pinocchio's
    layout when ``nq`` is given (continuous joints as (cos, sin)); a CSV's columns are matched by header
    name (a unit in parentheses ignored), else every column but frame and time is taken in order."""
    n = len(names)
    if path.suffix.lower() == ".csv" and path.exists():
        q = _csv_columns(path, names)
    else:
        q = np.asarray(_load_array(path, "joint angles", ("q", "truth_q")), dtype=float)
    if q.ndim != 2 or q.shape[1] not in {n, nq}:
        want = f"(frames, {n})" + (f" or (frames, {nq})" if nq not in (None, n) else "")
        raise TrackError(f"{path}: joint angles have shape {q.shape}, expected {want}")
    return q


def _csv_columns(path: Path, names: list[str]) -> np.ndarray:
    import csv

    with open(path, newline="", encoding="utf-8") as f:
        header = next(csv.reader(f), [])
    keys = [h.split("(")[0].strip() for h in header]
    if all(n in keys for n in names):
        cols = [keys.index(n) for n in names]
    else:
        cols = [i for i, k in enumerate(keys) if k.lower() not in ("frame", "time", "time_s", "t")]
    try:
        data = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, usecols=cols, ndmin=2)
    except ValueError as exc:
        raise TrackError(f"{path}: cannot read the joint angles: {exc}") from None
    return data


# An output as (option, its value) or (option, its value, the files it writes): "--out res" writes
# res/reconstruction.npz, ...; a value of None is an option not given.
Output = tuple[str, Any] | tuple[str, Any, list[Path]]


def _check_outputs(outputs: list[Output], overwrite: bool, inputs: dict[str, Any] | None = None) -> None:
    """Refuse, before any work, an output that is one of the command's ``inputs`` (role -> path), even
    with --overwrite (the input would be lost for good), then an existing output without --overwrite."""
    from .io.results import check_writable

    given = [(o[0], Path(o[1]), [Path(p) for p in (o[2] if len(o) > 2 else [o[1]])])
             for o in outputs if o[1] is not None]
    for option, value, files in given:
        for role, source in (inputs or {}).items():
            clash = next((f for f in files if source is not None and _same_file(f, Path(source))), None)
            if clash is not None:
                raise TrackError(f"{option} {value} would replace the input {role} {source}; choose another output")
    check_writable([f for _, _, files in given for f in files], overwrite)


def _same_file(a: Path, b: Path) -> bool:
    """Whether paths ``a`` and ``b`` name one file (links and ``..`` seen through)."""
    import os

    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except OSError:  # unreadable: the write or the read will say so
        return False


def _file_named(value: str | None) -> Path | None:
    """A --chain/--urdf/--map value as a path when it names a file (not a shipped name), else None."""
    return None if value is None or not Path(value).suffix else Path(value)


class Method(str, Enum):
    default = "default"
    kcs = "kcs"
    rigid = "rigid"


class Camera(str, Enum):
    static = "static"
    per_frame = "per-frame"


class ViewFrom(str, Enum):
    above = "above"
    below = "below"
    either = "either"


class Suite(str, Enum):
    reconstruction = "reconstruction"
    robots = "robots"
    speed = "speed"
    robustness = "robustness"
    hidden_ends = "hidden-ends"


Overwrite = Annotated[bool, typer.Option("--overwrite", help="Replace existing output files.")]
Markers = Annotated[Optional[str], typer.Option(
    "--markers", metavar="MAP",
    help="The tracks are ArUco marker centres ('chainspace markers'): the chain is the URDF's markers of "
         "this marker map CSV (or a shipped robot's name), those the tracks file names.")]
Intrinsics = Annotated[Optional[Path], typer.Option(
    help="The camera's calibration: OpenCV .yaml/.yml/.xml (calibrateCamera's output), ROS camera_info "
         ".yaml or .json with K and dist.")]
Fov = Annotated[Optional[float], typer.Option(
    help="Instead of --intrinsics: the horizontal field of view in degrees (needs --image-size).")]
ImageSize = Annotated[Optional[tuple[float, float]], typer.Option(
    help="Image width and height in px.")]


def _camera_option(intrinsics: Path | None, fov: float | None,
                   image_size: tuple[float, float] | None) -> Any:
    """The PinholeCamera that --intrinsics FILE or --fov DEG (with --image-size W H) describe, or None.

    Called before any work, so that a bad value stops the command at once (exit code 2).
    """
    size = _image_size(image_size)
    if intrinsics is None and fov is None:
        return None
    from .cameras.pinhole import PinholeCamera, as_camera
    from .errors import CameraError, DescriptionNotFoundError, is_real

    if intrinsics is not None and fov is not None:
        raise CameraError("give --intrinsics or --fov, not both")
    if fov is not None:
        if not is_real(fov) or not 0.0 < fov < 180.0:
            raise CameraError(f"--fov must be a field of view in degrees between 0 and 180, not {fov:g}")
        if size is None:
            raise CameraError("--fov needs the image size: add --image-size WIDTH HEIGHT")
        return PinholeCamera.from_fov(size[0], size[1], fov)
    if not intrinsics.is_file():
        raise DescriptionNotFoundError(f"{intrinsics}: no such calibration file (--intrinsics)")
    return as_camera(intrinsics, size)


def _image_size(image_size: tuple[float, float] | None) -> tuple[int, int] | None:
    """--image-size W H as whole pixels, or None; a clear error for anything else."""
    if image_size is None:
        return None
    from .errors import CameraError, is_real

    w, h = image_size
    if not (is_real(w) and is_real(h) and w > 0 and h > 0 and w == int(w) and h == int(h)):
        raise CameraError(f"--image-size must be two positive whole numbers of pixels, not {w:g} {h:g}")
    return int(w), int(h)


def _intrinsics_kwargs(func: Callable[..., Any], camera: Any, what: str) -> dict[str, Any]:
    """``{"intrinsics": camera}`` for ``func`` when a camera was given, else nothing; a clear error when
    this version of ``func`` takes no intrinsics (perspective support lands per stage)."""
    if camera is None:
        return {}
    import inspect

    if "intrinsics" not in inspect.signature(func).parameters:
        raise _fail(f"--intrinsics/--fov: {what} in this version of chainspace does not use camera "
                    "intrinsics yet", EXIT_BAD_INPUT)
    return {"intrinsics": camera}


# ---------------------------------------------------------------------------------------- commands
@app.command(epilog="Example: chainspace chains")
@_guarded
def chains() -> None:
    """List the chain descriptions shipped with chainspace, with their joint counts, and the
    example-robot-data robots that --chain and --urdf also take by name."""
    from .io.descriptions import EXAMPLE_ROBOTS, list_shipped, shipped

    for name in list_shipped():
        chain = shipped(name)
        kind = chain.metadata.get("kind", Path(name).suffix.lstrip("."))
        typer.echo(f"{Path(name).stem:<20} {chain.n_joints:>3} joints  {chain.n_bones:>3} bones  "
                   f"{len(chain.rigid_links):>2} rigid links  ({kind}, {name})")
    typer.echo(f"also by name, from example-robot-data when installed: {', '.join(EXAMPLE_ROBOTS)}")


@app.command(epilog="Example: chainspace reconstruct walk.csv --chain human17 --out results/ --bvh walk.bvh")
@_guarded
def reconstruct(
    tracks: Annotated[Path, typer.Argument(help="2D tracks: .csv, .npy, .npz, COCO/MediaPipe .json, "
                                                "or an OpenPose folder.")],
    chain: Annotated[str, typer.Option("--chain", "-c", help="Shipped name (chainspace chains) or a "
                                                             ".urdf/.asf/.bvh/.toml file.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for reconstruction.npz/.csv/.json, or a file "
                                                          "name ending .npz/.csv/.json whose suffix is replaced "
                                                          "(res/walk.npz: res/walk.npz, .csv, .json).")],
    init_pose: Annotated[Optional[Path], typer.Option(help="Initial pose (J, 3) in metres, .npy/.csv; "
                                                           "default the chain's rest pose.")] = None,
    method: Annotated[Method, typer.Option(help="default (KCS then refinement), kcs, or rigid.")] = Method.default,
    format: Annotated[Optional[str], typer.Option(help="Track format if not guessed: csv, npy, npz, coco, "
                                                       "openpose, mediapipe.")] = None,
    image_size: Annotated[Optional[tuple[float, float]], typer.Option(
        help="Image width and height in px (MediaPipe landmarks are normalised; --fov needs it).")] = None,
    intrinsics: Intrinsics = None,
    fov: Fov = None,
    truth: Annotated[Optional[Path], typer.Option(help="True poses (F, J, 3) m, .npy: adds the 3D error.")] = None,
    bvh: Annotated[Optional[Path], typer.Option(help="Also write the motion as BVH (human chains).")] = None,
    fps: Annotated[float, typer.Option(help="Frame rate of the tracks (BVH and viewer).")] = 30.0,
    html: Annotated[Optional[Path], typer.Option(help="Also write a standalone HTML viewer.")] = None,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    extra_frame: ExtraFrames = None,
    link: Links = None,
    markers: Markers = None,
    overwrite: Overwrite = False,
) -> None:
    """Reconstruct 3D motion from the 2D tracks of a chain seen by one camera.

    Writes reconstruction.npz (all arrays), reconstruction.csv (frame,joint,x,y,z in metres) and
    reconstruction.json (convergence, errors, timings) into --out (or --out's stem .npz/.csv/.json).
    Exit code 1 if it did not converge.
    """
    from .reconstruction.pipeline import reconstruct as run
    from .io.results import result_paths, save_results
    from .io.tracks import load_tracks

    _positive("--fps", fps)
    _seed(seed)
    for v in image_size or ():
        _positive("--image-size", v)
    camera = _camera_option(intrinsics, fov, image_size)
    extras = _parse_extra_frames(extra_frame)
    _check_outputs([("--out", out, result_paths(out, "reconstruction")), ("--bvh", bvh), ("--html", html)],
                   overwrite, {"tracks file": tracks, "initial pose": init_pose, "truth file": truth,
                               "calibration": intrinsics, "chain description": _file_named(chain),
                               "marker map": _file_named(markers)})
    intrinsics_kw = _intrinsics_kwargs(run, camera, "reconstruct")
    if markers is not None:
        _no_links_with_markers(link)
        kc = _marker_chain(_urdf_path(chain), markers, tracks, format)
    else:
        kc = _load_chain(chain, extras, link)
    W, conf, _ = load_tracks(tracks, chain=kc, format=format, image_size=image_size)
    X0 = None if init_pose is None else _load_array(init_pose, "initial pose", ("init_pose", "pose"))
    X_true = _load_poses(truth, kc)
    with _status(f"reconstructing {W.shape[0]} frames of {kc.name} ({method.value})"):
        rec = run(W, kc, X0, method.value, confidence=conf, truth=X_true, seed=seed, **intrinsics_kw)
    for p in save_results(rec, out, overwrite=overwrite):
        _say(f"wrote {p}")
    if bvh is not None:
        from .io.bvh import save_bvh
        from .view.viewer import upright_poses

        _say(f"wrote {save_bvh(bvh, kc, upright_poses(rec, truth=X_true), fps, overwrite)}")
    if html is not None:
        from .view.viewer import write_html

        _say(f"wrote {write_html(html, rec, truth=X_true, fps=fps, overwrite=overwrite, **_frustum(camera))}")
    typer.echo(repr(rec))
    if not rec.converged:
        raise _fail(f"the reconstruction did not converge: {rec.message}", EXIT_NOT_GOOD)


@app.command(epilog="Example: chainspace fit results/reconstruction.npz --urdf robots/milling_arm.urdf --out fit/")
@_guarded
def fit(
    source: Annotated[Path, typer.Argument(help="A reconstruction .npz of a URDF chain, or 2D tracks "
                                                "(reconstructed first).")],
    urdf: Annotated[Optional[str], typer.Option(help="The robot's URDF (file or shipped name); default "
                                                     "the one the reconstruction's chain came from.")] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for joint_angles.npz/.csv/.json, or a file name "
                                                          "ending .npz/.csv/.json whose suffix is replaced "
                                                          "(fit/arm.npz: fit/arm.npz, .csv, .json).")] = Path("."),
    camera: Annotated[Camera, typer.Option(help="static (tripod) or per-frame camera.")] = Camera.static,
    intrinsics: Intrinsics = None,
    fov: Fov = None,
    image_size: ImageSize = None,
    format: Annotated[Optional[str], typer.Option(help="Track format when SOURCE is tracks.")] = None,
    html: Annotated[Optional[Path], typer.Option(help="Also write a standalone HTML viewer of the fit.")] = None,
    fps: Annotated[float, typer.Option(help="Frame rate of the motion (the fit's motion prior and the "
                                            "viewer).")] = 30.0,
    extra_frame: ExtraFrames = None,
    link: Links = None,
    markers: Markers = None,
    perspective: Annotated[bool, typer.Option(
        "--perspective", help="Fit a pinhole camera even without --intrinsics/--fov/--image-size: focal "
                              "length and principal point estimated from the tracks (slower).")] = False,
    view_from: Annotated[ViewFrom, typer.Option(
        help="Where the camera stands: above the robot's base plane (or level), below it (a ceiling-mounted "
             "robot, a low tripod), or either (then of a motion and its mirror image, which weak perspective "
             "cannot tell apart, the one nearer the rest pose is reported).")] = ViewFrom.above,
    search_ties: Annotated[bool, typer.Option(
        "--search-ties/--no-search-ties", help="Also search for other motions that fit the tracks as well, "
                                               "and report the joints they leave ambiguous (on by default; "
                                               "--no-search-ties is faster and says less).")] = True,
    accel_std: Annotated[float, typer.Option(
        help="Motion prior: joint accelerations of this size (rad/s^2 RMS, at --fps) cost as much as the "
             "pixel noise; the fit widens it where the motion is faster, and says so.")] = 3.0,
    jerk_std: Annotated[float, typer.Option(
        help="The prior on joint jerks (rad/s^3 RMS) that the answer is finished under.")] = 10.0,
    speed_decay: Annotated[Optional[float], typer.Option(
        help="Seconds over which a joint comes to rest before its first and after its last sighting "
             "(default: it carries on at its last speed).")] = None,
    motion_prior: Annotated[bool, typer.Option(
        "--motion-prior/--no-motion-prior", help="Smooth the motion with the priors above (on by default; "
                                                 "--no-motion-prior fits every frame on its own).")] = True,
    overwrite: Overwrite = False,
) -> None:
    """Fit the robot's joint angles (Pinocchio) to a reconstruction or to 2D tracks.

    Writes joint_angles.npz, joint_angles.csv (frame, one column per joint, radians) and
    joint_angles.json into --out. Without a camera (--intrinsics, --fov) the fit assumes weak
    perspective; --image-size alone has the focal length estimated, --perspective the focal length
    and the principal point. Exit code 1 if some frames did not converge.
    """
    from .robot.fit import fit_joint_angles
    from .io.results import load_results, result_paths, save_results

    for option, value in (("--fps", fps), ("--accel-std", accel_std), ("--jerk-std", jerk_std),
                          ("--speed-decay", speed_decay)):
        _positive(option, value)
    extras = _parse_extra_frames(extra_frame)
    pinhole = _camera_option(intrinsics, fov, image_size)  # --camera is the static/per-frame choice
    _check_outputs([("--out", out, result_paths(out, "joint_fit")), ("--html", html)], overwrite,
                   {"reconstruction or tracks file": source, "URDF": _file_named(urdf), "calibration": intrinsics,
                    "marker map": _file_named(markers)})
    fit_kw = _intrinsics_kwargs(fit_joint_angles, pinhole, "fit")
    if pinhole is None and image_size is not None:  # the image's size without its focal: the focal is fitted
        fit_kw["image_size"] = _image_size(image_size)
    if perspective:
        fit_kw["perspective"] = True
    fit_kw.update(view_from=None if view_from is ViewFrom.either else view_from.value, search_ties=search_ties,
                  accel_std=accel_std if motion_prior else None, jerk_std=jerk_std if motion_prior else None,
                  speed_decay_s=speed_decay)
    urdf_path = None if urdf is None else _urdf_path(urdf)
    fit_chain = None
    if source.suffix.lower() == ".npz" and _is_result(source):
        rec = load_results(source)
        if not hasattr(rec, "poses"):
            raise TrackError(f"{source}: this is a joint fit, not a reconstruction")
        for option, given in (("--markers", markers is not None), ("--link", bool(link))):
            if given:
                raise TrackError(f"{option} goes with tracks; {source} is a reconstruction, which carries its chain "
                                 f"(give {option} to 'chainspace reconstruct', or fit the tracks file)")
        if extras:
            from .io.urdf import from_urdf

            base = urdf_path or getattr(getattr(rec, "chain", None), "metadata", {}).get("urdf_path")
            if base is None:
                raise TrackError("--extra-frame needs --urdf (the reconstruction names no URDF)")
            fit_chain = from_urdf(base, extra_frames=extras)
    else:
        if urdf_path is None:
            raise TrackError("fitting 2D tracks needs --urdf")
        from .reconstruction.pipeline import reconstruct as run
        from .io.tracks import load_tracks
        from .robot.kinematics import check_fittable

        check_fittable(urdf_path)  # a floating base: said before the reconstruction trips over its world link

        if markers is not None:
            _no_links_with_markers(link)
            kc = fit_chain = _marker_chain(urdf_path, markers, source, format)
        else:
            kc = _load_chain(urdf_path, extras, link)
        W, conf, _ = load_tracks(source, chain=kc, format=format)
        with _status(f"reconstructing {W.shape[0]} frames of {kc.name}"):
            rec = run(W, kc, confidence=conf, **_intrinsics_kwargs(run, pinhole, "reconstruct"))
    from .progress import print_stages

    # the fit's stages as lines with the elapsed time: it runs for minutes on long clips (issue 21)
    with _status(f"fitting joint angles to {rec.poses.shape[0]} frames"), print_stages():
        result = fit_joint_angles(rec, urdf_path, camera=camera.value, fps=fps, **fit_kw,
                                  **({} if fit_chain is None else {"chain": fit_chain}))
    for p in save_results(result, out, overwrite=overwrite):
        _say(f"wrote {p}")
    if html is not None:
        from .view.viewer import write_html

        _say(f"wrote {write_html(html, rec, fit=result, fps=fps, overwrite=overwrite, **_frustum(pinhole))}")
    typer.echo(_for_the_shell(repr(result)))
    if not np.all(result.converged):
        raise _fail(f"{int(np.sum(~np.asarray(result.converged)))} frames did not converge: "
                    f"{_for_the_shell(result.message)}",
                    EXIT_NOT_GOOD)


def _no_links_with_markers(links: list[str] | None) -> None:
    if links:
        raise TrackError("--link and --markers: the marker map names the tracked points (leave out --link)")


def _marker_chain(urdf: str | Path, markers: str, tracks: Path, format: str | None) -> Any:
    """The chain of the markers of a marker map that a tracks file names (each an extra frame of its link)."""
    from .io.tracks import load_tracks
    from .video.markers import load_marker_map, marker_chain, shipped_marker_map

    if Path(str(urdf)).suffix.lower() != ".urdf":
        raise TrackError(f"--markers needs a URDF chain; {urdf} is not a .urdf")
    map_path = Path(markers) if Path(markers).suffix else shipped_marker_map(markers)
    _, _, names = load_tracks(tracks, format=format)
    return marker_chain(urdf, load_marker_map(map_path, urdf=urdf), names=names)


def _frustum(camera: Any) -> dict[str, Any]:
    """``{"camera": camera}`` for the viewer when the camera's image size is known (the frustum needs it)."""
    return {} if camera is None or camera.image_size is None else {"camera": camera}


def _load_chain(chain: str | Path, extras: dict | None, links: list[str] | None) -> Any:
    """The chain a command tracks: the description (a file or a name), with the --extra-frame points
    (a URDF's only) and cut to the --link points, in their order."""
    from .io.descriptions import description_path, load_chain

    urdf = description_path(chain).suffix.lower() == ".urdf"
    if extras and not urdf:
        raise TrackError(f"--extra-frame needs a URDF chain; {chain} is not a .urdf")
    if not urdf:
        kc = load_chain(chain)
        return kc.subset(links) if links else kc
    return load_chain(chain, **({"extra_frames": extras} if extras else {}), **({"links": links} if links else {}))


def _urdf_path(urdf: str) -> str:
    from .io.descriptions import description_path

    return str(description_path(urdf))  # a file, a shipped name, or an example-robot-data robot ("ur5")


def _is_result(path: Path) -> bool:
    try:
        with np.load(path, allow_pickle=False) as z:
            return "kind" in z.files
    except (OSError, ValueError, EOFError):
        return False


def _thresholds(items: list[str]) -> dict[str, float]:
    """--threshold NAME=VALUE options as validate's thresholds (names and values checked here, in the
    command line's words)."""
    if not items:
        return {}
    from .robot.validation import DEFAULT_THRESHOLDS

    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name.strip() not in DEFAULT_THRESHOLDS:
            raise typer.BadParameter(f"{item!r}: give NAME=VALUE with NAME one of {', '.join(DEFAULT_THRESHOLDS)}",
                                     param_hint="--threshold")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not v > 0:  # NaN too
            raise typer.BadParameter(f"{item!r}: the value must be a positive number (inf: not judged)",
                                     param_hint="--threshold")
        out[name.strip()] = v
    return out


@app.command(epilog="Example: chainspace validate fit/joint_angles.npz --truth truth_q.npy --out fit/")
@_guarded
def validate(
    fit_file: Annotated[Path, typer.Argument(metavar="FIT", help="joint_angles.npz written by 'chainspace fit'.")],
    truth: Annotated[Optional[Path], typer.Option(help="True joint angles, one per joint (F, nv) "
                                                       "or Pinocchio's q (F, nq), rad/m: .npy, .csv or .npz ('q').")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Folder for validation.json/.md, or a file "
                                                                    "name ending .json/.md whose suffix is "
                                                                    "replaced.")] = None,
    threshold: Annotated[Optional[list[str]], typer.Option(
        metavar="NAME=VALUE", help="Set a check's threshold, repeatable: joint_rms_deg, error_3d_pct_reach (with "
                                   "--truth), tracks_misfit (without), reprojection_rms_px, bone_error_pct; "
                                   "inf: not judged.")] = None,
    overwrite: Overwrite = False,
) -> None:
    """Validate a joint-angle fit: per-joint angle errors and the 3D error against the truth, or without
    one whether the fitted robot explains its tracks; reprojection error, and bone lengths against the
    URDF. Prints the report table; exit code 1 if validation failed."""
    from .io.results import load_results, result_paths, save_results
    from .robot.validation import validate as run

    thresholds = _thresholds(threshold or [])
    if out is not None:
        _check_outputs([("--out", out, result_paths(out, "validation"))], overwrite,
                       {"fit": fit_file, "truth file": truth})
    fitted = load_results(fit_file)
    if not hasattr(fitted, "q"):
        raise TrackError(f"{fit_file}: not a joint fit (write one with 'chainspace fit')")
    truth_q = None if truth is None else _load_q(truth, list(fitted.joint_names), np.shape(fitted.q)[1])
    if truth_q is not None and len(truth_q) != len(fitted.q):
        raise TrackError(f"{truth}: {len(truth_q)} frames of joint angles for a fit of {len(fitted.q)} frames")
    report = run(fitted, truth_q, thresholds=thresholds or None)
    typer.echo(report.table())
    if out is not None:
        for p in save_results(report, out, overwrite=overwrite):
            _say(f"wrote {p}")
    if not report.passed:
        raise _fail("validation failed", EXIT_NOT_GOOD)


@app.command(epilog="Example: chainspace view results/reconstruction.npz --html walk.html")
@_guarded
def view(
    result: Annotated[Path, typer.Argument(help="reconstruction.npz or joint_angles.npz.")],
    html: Annotated[Optional[Path], typer.Option(help="Write a standalone HTML file instead of opening a "
                                                      "live viewer.")] = None,
    truth: Annotated[Optional[Path], typer.Option(help="True poses (F, J, 3) m, .npy, shown beside.")] = None,
    reconstruction: Annotated[Optional[Path], typer.Option(help="With a joint fit: the reconstruction to "
                                                                "draw over the robot.")] = None,
    fps: Annotated[Optional[float], typer.Option(help="Playback frame rate; default a joint fit's own (the "
                                                      "--fps it was fitted with), else 30.")] = None,
    intrinsics: Intrinsics = None,
    fov: Fov = None,
    image_size: ImageSize = None,
    open_browser: Annotated[bool, typer.Option("--open", help="Open the live viewer in a browser.")] = False,
    overwrite: Overwrite = False,
) -> None:
    """Animate a result in meshcat: the skeleton (and the truth beside it), or the fitted robot.

    With --html, writes one HTML file that a browser opens from disk with no server or network;
    otherwise starts a live viewer, prints its URL and runs until Ctrl-C. With --intrinsics (or --fov
    and --image-size) the camera's frustum is drawn where the result's fitted camera puts it.
    """
    from .io.results import load_results
    from .view.viewer import show, write_html

    _positive("--fps", fps)
    camera = _camera_option(intrinsics, fov, image_size)
    if camera is not None and camera.image_size is None:
        raise _fail(f"{intrinsics}: the calibration has no image size; add --image-size WIDTH HEIGHT to "
                    "draw the camera", EXIT_BAD_INPUT)
    kwargs_camera = {} if camera is None else {"camera": camera}
    _check_outputs([("--html", html)], overwrite, {"result": result, "truth file": truth,
                                                   "reconstruction": reconstruction, "calibration": intrinsics})
    loaded = load_results(result)
    if hasattr(loaded, "q"):
        rec = None if reconstruction is None else load_results(reconstruction)
        kwargs = {"fit": loaded, "truth": _load_poses(truth, loaded.chain)}
    else:
        rec, kwargs = loaded, {"truth": _load_poses(truth, loaded.chain)}
    if html is not None:
        _say(f"wrote {write_html(html, rec, fps=fps, overwrite=overwrite, **kwargs, **kwargs_camera)}")
        return
    show(rec, fps=fps, open_browser=open_browser, **kwargs, **kwargs_camera)
    _say("live viewer running; press Ctrl-C to stop")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass


@app.command(epilog="Example: chainspace overlay robot.mp4 fit/joint_angles.npz --out overlay.mp4 --side-by-side")
@_guarded
def overlay(
    video: Annotated[Path, typer.Argument(help="The footage the result was computed from: a video file (MP4, "
                                               "MOV, AVI) or a folder of numbered images.")],
    result: Annotated[Path, typer.Argument(help="joint_angles.npz ('chainspace fit') or reconstruction.npz "
                                                "('chainspace reconstruct').")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The overlay video (.mp4), or a folder of PNGs (a name without a suffix).")] = Path("overlay.mp4"),
    tracks: Annotated[Optional[Path], typer.Option(help="2D tracks to draw (any format load_tracks reads); "
                                                        "default the ones the result was fitted to.")] = None,
    side_by_side: Annotated[bool, typer.Option("--side-by-side", help="Add a 3D view beside every frame.")] = False,
    fps: Annotated[Optional[float], typer.Option(help="Frame rate of the overlay; default the video's own, 30 "
                                                      "for a folder of images.")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
    overwrite: Overwrite = False,
) -> None:
    """Draw a result over its footage: the fitted robot or reconstructed chain reprojected through the
    result's camera (green), the tracks (orange crosses), each point's reprojection error (red lines) and
    the frame's RMS error in pixels, on every frame."""
    from .video.overlay import draw_overlay

    _positive("--fps", fps)
    _check_outputs([("--out", out)], overwrite, {"video": video, "result": result, "tracks file": tracks})
    written = draw_overlay(video, result, tracks=tracks, out=out, side_by_side=side_by_side, overwrite=overwrite,
                           progress=progress, fps=fps)
    _say(f"wrote {written}")


# Benchmark suites: candidates (module, function returning rows, function formatting them), first found wins.
_SUITES = {
    "reconstruction": [("bench.reconstruction", "run_benchmark", "format_table")],
    "speed": [("bench.reconstruction", "run_speed", "format_speed")],
    "robustness": [("bench.robustness", "run_robustness", "format_robustness")],
    "robots": [("bench.robots", "run_robot_benchmark", "format_robot_table")],
    "hidden-ends": [("bench.hidden_ends", "run_hidden_ends", "format_hidden_ends")],
}


def _suite(name: str) -> tuple[Any, Callable[..., Any], Callable[..., str]]:
    import importlib

    for module, run_name, fmt_name in _SUITES[name]:
        try:
            mod = importlib.import_module(f".{module}", __package__)
            return mod, getattr(mod, run_name), getattr(mod, fmt_name)
        except (ImportError, AttributeError):
            continue
    raise _fail(f"the {name} benchmark is not available in this installation", EXIT_BAD_INPUT)


@app.command(epilog="Example: chainspace bench --suite robustness --quick --out bench-output")
@_guarded
def bench(
    suite: Annotated[Suite, typer.Option(help="Which benchmark.")] = Suite.reconstruction,
    quick: Annotated[bool, typer.Option("--quick", help="A short version (fewer sequences and cameras).")] = False,
    out: Annotated[Optional[Path], typer.Option("--out", "-o", help="Folder for the table (.md), the rows "
                                                                    "(.json) and plots.")] = None,
    overwrite: Overwrite = False,
) -> None:
    """Run a benchmark and print its table (millimetres, degrees, seconds)."""
    from .io.results import atomic_write, write_json

    stem = None if out is None else out / f"bench_{suite.value}"
    if stem is not None:
        _check_outputs([("--out", out, [stem.with_suffix(".md"), stem.with_suffix(".json")])], overwrite)
    mod, run, fmt = _suite(suite.value)
    console = _console()
    with console.status(f"running the {suite.value} benchmark{' (quick)' if quick else ''}") as status:
        def progress(message: str) -> None:
            console.print(message, markup=False, highlight=False)
            status.update(message)

        rows = run(quick=quick, progress=progress)
    if not rows:
        raise _fail(f"the {suite.value} benchmark found none of its data (CMU/DeepMimic sequences in "
                    "$CHAINSPACE_DATA, else ../shared/data beside the repository; example-robot-data for "
                    "robots): nothing was measured", EXIT_BAD_INPUT)
    table = fmt(rows)
    typer.echo(table)
    if stem is not None:
        with atomic_write(stem.with_suffix(".md"), "w", overwrite) as f:
            f.write(table.rstrip() + "\n")
        write_json(stem.with_suffix(".json"), [getattr(r, "__dict__", r) for r in rows], overwrite=overwrite)
        written = [stem.with_suffix(".md"), stem.with_suffix(".json")]
        if hasattr(mod, "plot_robustness") and suite is Suite.robustness:
            written += mod.plot_robustness(rows, out, overwrite=overwrite)
        for p in written:
            _say(f"wrote {p}")


@app.command(epilog="Example: chainspace markers arm.mp4 --map robots/milling_arm.markers.csv --out tracks.csv")
@_guarded
def markers(
    video: Annotated[Path, typer.Argument(help="A video file (MP4/MOV/AVI) or a folder of numbered images.")],
    map: Annotated[str, typer.Option("--map", help="The marker map CSV (id,link,x,y,z,roll,pitch,yaw,size), or "
                                                   "the name of a robot of robots/ that ships one (milling_arm).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The tracks CSV to write (frame, joint, x, y, "
                                                          "confidence; one point per marker seen).")],
    urdf: Annotated[Optional[str], typer.Option(help="Check the map's links against this URDF (file or "
                                                     "shipped name).")] = None,
    overwrite: Overwrite = False,
) -> None:
    """Find the ArUco markers of a marker map in every frame of a video and write their centres as tracks.

    Each marker is a point named marker_<id>, an extra frame of its link: fit the tracks with
    chainspace.video.markers.marker_chain(urdf, map) (see the robot-from-video tutorial). The detected
    corners go to <out>.corners.npz (corners (F, M, 4, 2) px, NaN where not seen).
    """
    from .io.results import atomic_write
    from .video.markers import detect_markers, load_marker_map, save_marker_tracks, shipped_marker_map

    map_path = Path(map) if Path(map).suffix else shipped_marker_map(map)
    urdf_path = None if urdf is None else Path(_urdf_path(urdf))  # a file, a shipped or example robot name
    mmap = load_marker_map(map_path, urdf=urdf_path)
    corners_path = out.with_name(out.stem + ".corners.npz")
    _check_outputs([("--out", out, [out, corners_path])], overwrite,
                   {"video": video, "marker map": map_path, "URDF": urdf_path})
    found = detect_markers(video, mmap, progress=sys.stderr.isatty())
    save_marker_tracks(out, found, overwrite=overwrite)
    with atomic_write(corners_path, "wb", overwrite) as fh:
        np.savez_compressed(fh, corners=found.corners, names=np.array(found.names), fps=np.array(found.fps),
                            image_size=np.array(found.image_size))
    _say(f"wrote {out} ({len(found.seen)} of {len(found.names)} markers seen in {len(found.corners)} frames) "
         f"and {corners_path}")


@app.command(epilog="Example: chainspace demo --out demo-output --overwrite")
@_guarded
def demo(
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder for everything the demo writes.")] =
    Path("demo-output"),
    seed: Annotated[int, typer.Option(help="Random seed of the rendered clip (the path's placement, the camera "
                                           "and the textures; see chainspace.demo.run_demo).")] = 8,
    frames: Annotated[int, typer.Option(help="Frames of the filmed motion (fewer: a quicker look).")] = 300,
    overwrite: Overwrite = False,
) -> None:
    """The main job on bundled data: the milling arm filmed by one camera, reconstructed, its joint angles
    fitted and validated. Writes into --out the fitted joint angles, the validation report, plots and a
    standalone HTML viewer (viewer.html). Exit code 1 if validation failed."""
    from .demo import run_demo

    _seed(seed)
    if frames < 10:
        raise _fail(f"--frames must be at least 10, not {frames}", EXIT_BAD_INPUT)
    console = _console()
    with console.status("running the demo") as status:
        def progress(message: str) -> None:
            if not message.lstrip().startswith("|"):  # the report table goes to stdout at the end
                console.print(message.strip(), markup=False, highlight=False, soft_wrap=True)
                status.update(message.strip())

        summary = run_demo(out, overwrite=overwrite, progress=progress, seed=seed, n_frames=frames)
        progress("writing the viewer (viewer.html) and the plots (joint_angles.png, convergence.png, "
                 "joint_errors.png)")
        status.update("writing the viewer and the plots")
        for p in _demo_extras(out, summary, overwrite):
            _say(f"wrote {p}")
    if isinstance(summary.get("table"), str):
        typer.echo(summary["table"])
    if summary.get("passed") is False:
        raise _fail("the demo's validation failed", EXIT_NOT_GOOD)


def _demo_extras(out: Path, summary: dict, overwrite: bool) -> list[Path]:
    """The viewer and plots for a demo run, from the objects (or files) its summary names."""
    from .view.plots import plot_convergence, plot_joint_angles, plot_joint_errors
    from .io.results import load_results
    from .view.viewer import write_html

    def obj(key: str, file_key: str) -> Any:
        if summary.get(key) is not None:
            return summary[key]
        path = summary.get(file_key)
        return load_results(path) if path else None

    rec, fitted = obj("reconstruction", "reconstruction_path"), obj("fit", "fit_path")
    report, truth_q, truth = summary.get("report"), summary.get("truth_q"), summary.get("truth_positions")
    written = []
    if fitted is not None:
        written.append(write_html(out / "viewer.html", rec, fit=fitted, truth=truth, overwrite=overwrite))
        written.append(plot_joint_angles(fitted, truth_q, out / "joint_angles.png", overwrite=overwrite))
    if rec is not None and getattr(rec, "history", None):
        written.append(plot_convergence(rec, out / "convergence.png", fit=fitted, overwrite=overwrite))
    if report is not None:
        written.append(plot_joint_errors(report, out / "joint_errors.png", overwrite=overwrite))
    return written


@app.command(epilog="Example: chainspace batch recordings.csv --out batch-output --scheduler tcp://head:8786")
@_guarded
def batch(
    manifest: Annotated[Path, typer.Argument(help="CSV with a header row, one recording a row: name,tracks,chain "
                                                  "and optional urdf,intrinsics,fps,truth (paths relative to "
                                                  "the manifest).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Folder: one sub-folder per recording, "
                                                          "summary.csv and summary.html.")],
    scheduler: Annotated[Optional[str], typer.Option(help="Address of a running Dask scheduler "
                                                          "(tcp://host:8786); default a local cluster.")] = None,
    workers: Annotated[Optional[int], typer.Option(help="Workers of the local cluster (default one per "
                                                        "core).", min=1)] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar on stderr.")] = True,
) -> None:
    """Reconstruct (and for robots fit and validate) every recording of a manifest on Dask.

    Each recording's files go to OUT/NAME/ (written to a temporary folder renamed at the end); a
    recording finished by an earlier run is skipped, so an interrupted batch resumes. A failing
    recording is reported in the summary and does not stop the others. Prints the summary table.
    Exit code 1 if some recording failed or did not converge, 2 for a manifest that cannot be used.
    """
    from .batch import run_batch

    # the summary is rewritten on every run (a resumed batch updates it): only an input is protected
    _check_outputs([("--out", out, [out / "summary.csv", out / "summary.html"])], True, {"manifest": manifest})
    result = run_batch(manifest, out, scheduler=scheduler, n_workers=workers, progress=progress)
    shown = ("name", "status", "frames", "seconds", "reprojection_px", "worst_joint", "worst_joint_rms", "error")
    typer.echo("| " + " | ".join(shown) + " |\n|" + "---|" * len(shown))
    for row in result.rows:
        cells = [row.get(k) for k in shown]
        typer.echo("| " + " | ".join("" if v is None else f"{v:.3g}" if isinstance(v, float) else str(v)
                                     for v in cells) + " |")
    for p in (result.summary_csv, result.summary_html):
        _say(f"wrote {p}")
    _say(repr(result))
    if not result.ok:
        raise _fail(f"{_count(len(result.failed), 'recording')} failed, {len(result.not_good)} did not converge "
                    "or failed validation (see the summary)", EXIT_NOT_GOOD)


@app.command(epilog="Example: chainspace track arm.mp4 --points keyframes.json --chain milling_arm --out tracks.csv")
@_guarded
def track(
    video: Annotated[Path, typer.Argument(help="A video file (MP4, MOV, AVI, ...) or a folder of numbered "
                                               "PNG/JPEG frames.")],
    points: Annotated[Path, typer.Option("--points", "-p", help='Key frames JSON: {"0": {"name": [x, y], '
                                                                 '...}, "120": {...}} in pixels.')],
    out: Annotated[Path, typer.Option("--out", "-o", help="The tracks CSV (frame,joint,x,y,confidence).")],
    fps: Annotated[Optional[float], typer.Option(help="Frame rate (needed for an image folder).")] = None,
    chain: Annotated[Optional[str], typer.Option("--chain", "-c", help="Shipped name or description file: "
                                                                       "the tracks get its joints, in order.")] = None,
    window: Annotated[Optional[int], typer.Option(
        help="Side of the patch tracked around each point, px (odd); default 21 up to 480 rows, 31 at 1080.")] = None,
    levels: Annotated[int, typer.Option(help="Pyramid levels above the full image.")] = 3,
    fb_max_px: Annotated[float, typer.Option("--fb-max-px", help="Forward-backward error beyond which a "
                                                                 "point is lost, px.")] = 1.0,
    refine: Annotated[bool, typer.Option(help="Align each point's key-frame patch to every frame (rotation "
                                              "and shift, ECC) after the LK step.")] = True,
    progress: Annotated[bool, typer.Option(help="Show progress on stderr.")] = True,
    overwrite: Overwrite = False,
) -> None:
    """Track the key frames' points through a video (pyramidal Lucas-Kanade, forward-backward check).

    Writes the tracks as CSV, the layout `chainspace reconstruct` reads; lost points are empty with
    confidence 0. Prints the drift measured at each later key frame (re-anchor). Make the key frames
    with `chainspace pick`.
    """
    from .video.tracking import track_video

    _positive("--fps", fps)
    _positive("--fb-max-px", fb_max_px)
    _check_outputs([("--out", out)], overwrite, {"video": video, "key-frame file": points,
                                                 "chain description": _file_named(chain)})
    result = track_video(video, points, out, chain=chain, fps=fps, overwrite=overwrite, progress=progress,
                         window=window, levels=levels, fb_max_px=fb_max_px, refine=refine)
    _say(f"wrote {out}")
    for frame, drift in result.drift.items():
        cells = ", ".join(f"{n} {d:.2f} px" if np.isfinite(d) else f"{n} lost before" for n, d in drift.items())
        _say(f"drift at key frame {frame}: {cells}")
    typer.echo(f"{repr(result)}; {result.n_frames / result.seconds:.0f} frames/s")


@app.command(epilog="Example: chainspace pick arm.mp4 --frame 0 --chain milling_arm --out picker.html")
@_guarded
def pick(
    video: Annotated[Path, typer.Argument(help="A video file or a folder of numbered PNG/JPEG frames.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="The HTML page to write.")],
    frame: Annotated[list[int], typer.Option("--frame", "-f", help="Frame to show (0-based); repeat for "
                                                                   "several key frames.")] = [0],  # noqa: B006
    chain: Annotated[Optional[str], typer.Option("--chain", "-c", help="Shipped name or description file: "
                                                                       "its joints are the points.")] = None,
    names: Annotated[Optional[str], typer.Option(help="Point names in clicking order, comma-separated "
                                                      "(instead of --chain).")] = None,
    fps: Annotated[Optional[float], typer.Option(help="Frame rate of an image folder (unused otherwise).")] = None,
    overwrite: Overwrite = False,
) -> None:
    """Write a standalone HTML page to click the chain's points on video frames.

    Open it in a browser, click the points in the listed order, and copy or download the key-frame
    JSON for `chainspace track --points`.
    """
    from .video.picker import write_picker

    _positive("--fps", fps)
    if any(f < 0 for f in frame):
        raise TrackError(f"--frame must be >= 0, not {min(frame)}")
    point_names = None if names is None else [n.strip() for n in names.split(",") if n.strip()]
    _check_outputs([("--out", out)], overwrite, {"video": video, "chain description": _file_named(chain)})
    _say(f"wrote {write_picker(video, out, frame, chain=chain, names=point_names, fps=fps, overwrite=overwrite)}")


def main() -> None:  # pragma: no cover - the console script
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
