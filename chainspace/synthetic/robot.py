"""Synthetic robot footage: a known joint trajectory filmed by a known camera, as 2D tracks.

:func:`synthesize` is how a user checks a camera set-up before filming: it moves the robot of a URDF
along a smooth trajectory inside its joint limits, films it with a realistic static pinhole camera (a
phone or an industrial camera with a 6-12 mm lens, some with lens distortion; weak-perspective cameras,
static or slowly orbiting, as options), adds pixel noise and dropped points, and returns the tracks with
the truth (joint angles, 3D points, cameras). Fit the tracks with :func:`chainspace.fit_joint_angles`
and compare with :func:`chainspace.validate`.

Units: metres, radians, pixels (image y axis pointing down); q in the order of Pinocchio's model of the
URDF. Forward and inverse kinematics are Pinocchio's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..chain import KinematicChain
from ..errors import DescriptionError, TrackError, is_real
from ..robot.kinematics import RobotKinematics

__all__ = ["RobotTrial", "synthesize", "random_trajectory", "milling_trajectory", "singular_trajectory",
           "conditioning", "CAMERAS", "TRAJECTORIES", "JOINT_RANGES"]

CAMERAS = ("pinhole", "phone", "industrial", "static", "weak", "moving")
TRAJECTORIES = ("random", "milling", "singular")
JOINT_RANGES = ("comfort", "full")
# industrial camera: a 1/1.2" sensor 11.3 mm wide imaged at 1920 x 1200 px (5.86 um pixels), lenses of 6-12 mm
SENSOR_WIDTH_MM, INDUSTRIAL_SIZE = 11.3, (1920, 1200)


@dataclass
class RobotTrial:
    """A synthetic recording of a robot: the truth and what a tracker would see.

    chain (points = URDF link origins and tool frames), q (F, nq) radians/metres in Pinocchio order,
    positions (F, J, 3) metres in the robot's base frame, cameras (F, 2, 3) px per metre (rows: image
    right, image down; ``tracks = positions @ cameras^T + translations + noise``), translations (F, 2)
    px, tracks (F, J, 2) px with NaN where a point was dropped, confidence (F, J) in [0, 1], fps.

    Filmed through a pinhole camera (``synthesize(camera="pinhole")``): ``intrinsics`` (``K``, ``dist``),
    the pose ``camera_R``, ``camera_t`` (``x_cam = camera_R @ x + camera_t``, metres) and ``image_size``
    (w, h) are the truth; ``cameras``/``translations`` then hold the weak-perspective camera that
    linearises it at the depth of the robot's points (an approximation, for plotting).
    """

    chain: KinematicChain
    q: np.ndarray
    positions: np.ndarray
    cameras: np.ndarray
    translations: np.ndarray
    tracks: np.ndarray
    confidence: np.ndarray
    fps: float
    urdf_path: str = ""
    noise_px: float = 0.0
    trajectory: str = "random"
    intrinsics: Any = None  # pinhole filming: the camera (K (3, 3), dist (5,), undistort), else None
    camera_R: np.ndarray | None = None  # pinhole: x_cam = camera_R @ x_base + camera_t (metres)
    camera_t: np.ndarray | None = None
    image_size: tuple[int, int] | None = None

    @property
    def n_frames(self) -> int:
        return len(self.q)


# ---------------------------------------------------------------------------------------------------
# trajectories
# ---------------------------------------------------------------------------------------------------
def _window(robot: RobotKinematics, margin: float = 0.1, full: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per degree of freedom (nv) the range a trajectory may use, less a margin at each end.

    ``full=False`` ("comfort"): the joint limits, but at most 72 degrees either side of the rest pose for
    revolute joints. Within it the fit's rule for discrete ambiguities (of two wrist configurations that
    put every tracked point in the same place, the one nearer the rest pose; see :mod:`chainspace.robot.fit`)
    picks the true one. ``full=True``: the URDF limits, continuous joints (and unlimited ones) +-pi
    about rest, where that rule can pick wrong: the range a benchmark must cover."""
    span = np.pi if full else 0.4 * np.pi
    rest = robot.angles(robot.q_rest)  # per degree of freedom (nv): continuous joints as angles
    lo = np.where(robot.limited_v, robot.lower_v, rest - span)
    hi = np.where(robot.limited_v, robot.upper_v, rest + span)
    if not full:
        rev = robot.turns_v
        lo = np.where(rev, np.maximum(lo, rest - span), lo)
        hi = np.where(rev, np.minimum(hi, rest + span), hi)
    pad = margin * (hi - lo)
    return lo + pad, hi - pad


def _sinusoids(robot: RobotKinematics, n_frames: int, fps: float, rng: np.random.Generator,
               amplitude: float, max_hz: float, full: bool = False) -> np.ndarray:
    t = np.arange(n_frames)[:, None, None] / float(fps)
    lo, hi = _window(robot, full=full)
    freq = rng.uniform(0.2, 1.0, (1, robot.nv, 3)) * max_hz
    phase = rng.uniform(0, 2 * np.pi, (1, robot.nv, 3))
    weights = rng.dirichlet(np.ones(3), robot.nv)[None]
    wave = (weights * np.sin(2 * np.pi * freq * t + phase)).sum(-1)
    centre = 0.5 * (lo + hi) + rng.uniform(-0.5, 0.5, robot.nv) * (hi - lo) * (1 - amplitude)
    a = centre + amplitude * 0.5 * (hi - lo) * wave / max(np.abs(wave).max(), 1e-12)
    return robot.clip(robot.from_angles(a))  # continuous joints' angles as (cos, sin)


def conditioning(robot: RobotKinematics, q: np.ndarray, seen: np.ndarray | None = None) -> np.ndarray:
    """(F,) smallest singular value of the Jacobian of the tracked points (metres per radian) over the
    joints that move them. Near zero at a singularity: a wrist stretched straight, or a 7-axis arm's
    shoulder with its upper arm along the first axis, where two joints' axes align and only their sum
    is seen. The first joint counts even where a turn of the whole robot imitates it: aligned with the
    third, the two trade angle freely, and the arm can pass on to a second branch that fits every
    tracked point alike (both turned half a turn, the second joint mirrored)."""
    from ..robot.observability import _structural

    seen = np.ones(robot.chain.n_joints, bool) if seen is None else seen
    blind, _ = _structural(robot, seen[None].astype(float))
    keep = ~blind
    _, jac = robot.jacobians(q)
    J = jac[:, seen][..., keep].reshape(len(q), -1, int(keep.sum()))
    return np.linalg.svd(J, compute_uv=False)[:, -1] if keep.any() else np.full(len(q), np.inf)


def _typical_conditioning(robot: RobotKinematics, rng: np.random.Generator, full: bool = False) -> float:
    """Median :func:`conditioning` of random configurations inside the trajectory window."""
    lo, hi = _window(robot, full=full)
    probe = robot.clip(robot.from_angles(rng.uniform(lo, hi, (64, robot.nv))))
    return float(np.median(conditioning(robot, probe)))


def _well_conditioned(robot: RobotKinematics, rng: np.random.Generator, tries: int, make,
                      full: bool = False) -> np.ndarray:
    """Of up to ``tries`` paths (F, nq) from ``make()``, the first whose :func:`conditioning` (on about
    60 frames) stays above half the robot's typical value, else the best."""
    typical = _typical_conditioning(robot, rng, full)
    best, best_c = None, -np.inf
    for _ in range(tries):
        q = make()
        c = float(conditioning(robot, q[:: max(1, len(q) // 60)]).min())
        if c > best_c:
            best, best_c = q, c
        if c >= typical / 2:
            break
    return best


def random_trajectory(robot: RobotKinematics, n_frames: int, fps: float, rng: np.random.Generator,
                      *, amplitude: float = 0.45, max_hz: float = 0.3, tries: int = 40,
                      full: bool = False) -> np.ndarray:
    """Smooth random joint motion (F, nq) away from singularities.

    Per joint a sum of three sinusoids of random low frequency (at most ``max_hz``) and phase, about a
    random centre of its window (:func:`_window`; ``full``: the whole joint range), reaching
    ``amplitude`` of the window's half width, clipped into the limits. Of up to ``tries`` such motions
    the first whose :func:`conditioning` stays above half the robot's typical value is taken (else the
    best): near a singularity joints cannot be told apart by any camera, which says nothing about a
    camera set-up (:func:`singular_trajectory` goes through one on purpose).
    """
    return _well_conditioned(robot, rng, tries,
                             lambda: _sinusoids(robot, n_frames, fps, rng, amplitude, max_hz, full), full)


def _singular_pose(robot: RobotKinematics, rng: np.random.Generator, full: bool, sweeps: int = 2,
                   grid: int = 25) -> np.ndarray:
    """(nq,) a configuration where :func:`conditioning` is (near) its minimum: of 128 random ones the
    worst, then each joint in turn set to the value on a grid over its window that lowers it most (a
    wrist stretched straight: two axes aligned)."""
    lo, hi = _window(robot, 0.05, full)
    a = rng.uniform(lo, hi, (128, robot.nv))
    a = a[int(np.argmin(conditioning(robot, robot.clip(robot.from_angles(a)))))]
    for _ in range(sweeps):
        for v in range(robot.nv):
            trial = np.repeat(a[None], grid, 0)
            trial[:, v] = np.linspace(lo[v], hi[v], grid)
            a = trial[int(np.argmin(conditioning(robot, robot.clip(robot.from_angles(trial)))))]
    return robot.clip(robot.from_angles(a[None]))[0]


def singular_trajectory(robot: RobotKinematics, n_frames: int, fps: float, rng: np.random.Generator,
                        *, amplitude: float = 0.3, max_hz: float = 0.3, full: bool = False) -> np.ndarray:
    """Smooth joint motion (F, nq) that passes through a singularity in its middle frame.

    A singular configuration (:func:`_singular_pose`: typically the wrist stretched straight, where two
    joint axes align and only the sum of their angles is seen) plus, per joint, a smooth random motion
    (as :func:`random_trajectory`) that is zero in the middle frame, reaching ``amplitude`` of the
    window's half width; clipped into the limits. The path a robot programmer avoids and a benchmark
    must include: near the middle frame no camera splits the aligned joints.
    """
    lo, hi = _window(robot, full=full)
    q0 = _singular_pose(robot, rng, full)
    t = (np.arange(n_frames)[:, None, None] - n_frames // 2) / float(fps)
    freq = rng.uniform(0.2, 1.0, (1, robot.nv, 3)) * max_hz
    phase = rng.uniform(0, 2 * np.pi, (1, robot.nv, 3))
    weights = rng.dirichlet(np.ones(3), robot.nv)[None]
    wave = (weights * (np.sin(2 * np.pi * freq * t + phase) - np.sin(phase))).sum(-1)
    a = robot.angles(q0[None]) + amplitude * 0.5 * (hi - lo) * wave / max(np.abs(wave).max(), 1e-12)
    return robot.clip(robot.from_angles(a))


def _tip_index(chain: KinematicChain) -> int:
    """The deepest point of the chain (the tool tip when one is tracked)."""
    depth = np.zeros(chain.n_joints, int)
    parents = chain.parents
    for j in range(chain.n_joints):
        k = j
        while parents[k] >= 0:
            depth[j] += 1
            k = parents[k]
    return int(np.argmax(depth))


def _rounded_rectangle(n: int, width: float, height: float, radius: float) -> np.ndarray:
    """(n, 2) points evenly spaced by arc length along a closed rounded rectangle centred at 0."""
    a, b, r = width / 2 - radius, height / 2 - radius, radius
    segs = [2 * b, 0.5 * np.pi * r, 2 * a, 0.5 * np.pi * r, 2 * b, 0.5 * np.pi * r, 2 * a, 0.5 * np.pi * r]
    ends = np.cumsum(segs)
    s = np.linspace(0, ends[-1], n, endpoint=False)
    out = np.empty((n, 2))
    corners = [(a, b, 0.0), (-a, b, 0.5 * np.pi), (-a, -b, np.pi), (a, -b, 1.5 * np.pi)]
    starts = np.concatenate([[0], ends[:-1]])
    for i in range(8):
        m = (s >= starts[i]) & (s < ends[i])
        d = s[m] - starts[i]
        side = i // 2
        if i % 2 == 0:  # straight side, counter-clockwise
            p0 = [(a + r, -b), (a, b + r), (-a - r, b), (-a, -b - r)][side]
            dirn = [(0, 1), (-1, 0), (0, -1), (1, 0)][side]
            out[m] = np.array(p0) + d[:, None] * np.array(dirn)
        else:
            cx, cy, ang0 = corners[side]
            ang = ang0 + d / r
            out[m] = np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], -1)
    return out


def _working_pose(robot: RobotKinematics, tip: int, rng: np.random.Generator, n: int = 400,
                  full: bool = False) -> np.ndarray:
    """A configuration to mill from: dexterous (large manipulability of the tip), tool pointing down,
    tip in front of the robot between its base and shoulder height."""
    pin = robot.pin
    lo, hi = _window(robot, 0.2, full)
    qs = robot.clip(robot.from_angles(rng.uniform(lo, hi, (n, robot.nv))))
    pos, jac = robot.jacobians(qs)
    base = pos[:, robot.chain.joint_index(robot.chain.root)]
    reach = robot.reach()
    fid = robot.frame_ids[tip]
    score = np.empty(n)
    for k, q in enumerate(qs):
        J6 = pin.computeFrameJacobian(robot.model, robot.data, q, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        down = -robot.data.oMf[fid].rotation[2, 2]  # tool z axis pointing down
        manip = np.sqrt(max(np.linalg.det(J6 @ J6.T), 0.0)) if J6.shape[1] >= 6 else \
            np.sqrt(max(np.linalg.det(jac[k, tip] @ jac[k, tip].T), 0.0))
        h = (pos[k, tip, 2] - base[k, 2]) / reach
        r = np.linalg.norm(pos[k, tip, :2] - base[k, :2]) / reach
        score[k] = manip ** (1 / 6) * (1 + down) * (0.1 < h < 0.5) * (0.35 < r < 0.75)
    return qs[int(np.argmax(score))]


def milling_trajectory(robot: RobotKinematics, n_frames: int, rng: np.random.Generator,
                       *, size: float = 0.2, laps: float = 1.0, tries: int = 10, full: bool = False) -> np.ndarray:
    """Joint motion (F, nq) whose tool tip (the deepest chain point) traces a rounded rectangle in a
    horizontal plane, from a dexterous working pose, solved by damped least-squares IK on the tip's
    position (Pinocchio frame Jacobian; minimum-norm steps, so the other joints move as little as they
    can), warm-started frame to frame, inside the limits. ``size`` is the rectangle's longer side as a
    fraction of the robot's reach.

    Of up to ``tries`` working poses the first whose path keeps :func:`conditioning` above half the
    robot's typical value is taken (else the best): a path through a wrist singularity (the wrist
    stretched straight) is one a robot programmer avoids, and no camera can split the joints there.
    ``full``: working poses drawn over the whole joint ranges.
    """
    return _well_conditioned(robot, rng, tries, lambda: _milling_path(robot, n_frames, rng, size, laps, full), full)


def _milling_path(robot: RobotKinematics, n_frames: int, rng: np.random.Generator, size: float,
                  laps: float, full: bool = False) -> np.ndarray:
    tip = _tip_index(robot.chain)
    q = _working_pose(robot, tip, rng, full=full)
    start = robot.positions(q)[0, tip]
    reach = robot.reach()
    w, h = size * reach, 0.6 * size * reach
    path = _rounded_rectangle(max(int(round(n_frames / laps)), 2), w, h, 0.2 * h)
    path = np.resize(path, (n_frames, 2)) - path[0]  # start where the tool is
    yaw = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    path = path @ np.array([[c, s], [-s, c]])
    out = np.empty((n_frames, robot.nq))
    for f in range(n_frames):
        target = start + np.array([path[f, 0], path[f, 1], 0.0])
        for _ in range(50):
            pos, jac = robot.jacobians(q[None])
            err = pos[0, tip] - target
            if np.linalg.norm(err) < 1e-9:
                break
            J = jac[0, tip]
            v = -J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(3), err)
            q = robot.integrate(q[None], v[None])[0]
        out[f] = q
    return out


# ---------------------------------------------------------------------------------------------------
# filming
# ---------------------------------------------------------------------------------------------------
def synthesize(
    urdf_or_chain: str | Path | KinematicChain,
    *,
    n_frames: int = 300,
    fps: float = 30.0,
    camera: Any = "pinhole",
    noise_px: float = 1.0,
    drop: float = 0.0,
    image_height_px: float = 800.0,
    seed: Any = None,
    trajectory: str | None = "random",
    joint_range: str = "comfort",
    elevation_deg: float | None = None,
    distance_reaches: float | None = None,
    image_size: tuple[int, int] | None = None,
    focal_px: float | None = None,
    dist: Any = None,
) -> RobotTrial:
    """Film a robot moving along a known trajectory.

    Parameters
    ----------
    urdf_or_chain
        A URDF path, or a chain made by :func:`chainspace.from_urdf` (its points are tracked).
    n_frames, fps
        Length and frame rate of the recording.
    camera
        The default, ``"pinhole"``, is a realistic static camera drawn from the seed: half the time a
        phone (``"phone"``: 1920 x 1080 px, focal 0.8-1.2 x the width, no distortion: phones correct it),
        else an industrial camera (``"industrial"``: 1920 x 1200 px on an 11.3 mm sensor, a 6-12 mm lens,
        barrel distortion k1 in [-0.25, -0.05], k2 in [0, 0.08]); with ``focal_px`` given, a phone. It stands 1.5-4 robot reaches
        (``distance_reaches``) from the centre of the trajectory's points, moved back when needed so
        that every point stays in the image, at a random azimuth and the elevation below. Also a camera
        object with ``K`` (and ``dist``), or a 3x3 matrix K. Weak perspective as options: ``"static"``
        (``"weak"``; one camera, a tripod far away) or ``"moving"`` (orbits 10 degrees about the
        vertical over the sequence), the robot spanning ``image_height_px``.
        Elevation random in [10, 35] degrees above the base plane unless ``elevation_deg`` is given
        (negative: below it, as for a ceiling-mounted robot or a low tripod).
    noise_px
        Standard deviation of Gaussian noise per image coordinate, pixels.
    drop
        Fraction of points dropped at random (NaN in the tracks, confidence 0).
    image_height_px
        Weak perspective only: the robot's extent in the image over the sequence (the larger side of its
        bounding box), px.
    trajectory
        ``"random"`` (smooth random motion of every joint, away from singularities), ``"milling"`` (the
        tool tip traces a rounded rectangle in a horizontal plane, tool orientation held) or
        ``"singular"`` (smooth random motion through a singular configuration in the middle frame: two
        joint axes aligned, e.g. a wrist stretched straight; see :func:`singular_trajectory`).
    joint_range
        ``"comfort"`` (revolute joints within 72 degrees of rest, inside the limits: where the fit's
        tie rules pick right) or ``"full"`` (the URDF limits; continuous joints +-180 degrees).
    image_size, focal_px, dist
        Pinhole cameras (:class:`chainspace.cameras.PinholeCamera` projects, distortion included): image
        (width, height) px (principal point at its centre unless K gives one; a camera's own size wins);
        focal length px; lens distortion (k1, k2, p1, p2, k3) applied to the tracks (OpenCV's model).
        Given, each overrides what the camera kind would draw.
    seed
        Seed for the trajectory, camera, noise and drops.
    """
    def number(name: str, value: Any, ok, need: str) -> float:
        # a real number (not a bool, string or array), finite, and within its range
        if not (is_real(value) and ok(float(value))):
            raise TrackError(f"{name} must be {need}, not {value!r}")
        return float(value)

    if (isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 2):
        raise TrackError(f"n_frames must be an integer of at least 2, not {n_frames!r}")
    n_frames = int(n_frames)
    fps = number("fps", fps, lambda v: v > 0, "a finite number > 0 (frames per second)")
    noise_px = number("noise_px", noise_px, lambda v: v >= 0, "a finite number >= 0 (pixels)")
    drop = number("drop", drop, lambda v: 0 <= v < 1, "a fraction in [0, 1)")
    image_height_px = number("image_height_px", image_height_px, lambda v: v > 0, "a finite number > 0 (pixels)")
    if elevation_deg is not None:
        elevation_deg = number("elevation_deg", elevation_deg, lambda v: -90 < v < 90,
                               "None or a number of degrees in (-90, 90)")
    pinhole_cam = None
    if isinstance(camera, str) and camera == "weak":
        camera = "static"
    need = ("camera must be " + ", ".join(map(repr, CAMERAS)) +
            " or a camera (a PinholeCamera, a 3x3 K or a calibration file)")
    if not isinstance(camera, str):
        from ..cameras.pinhole import as_camera
        from ..errors import CameraError

        try:
            pinhole_cam = as_camera(camera)
        except CameraError as exc:
            raise CameraError(f"{need}, not {camera!r}: {exc}") from None
        camera = "given"
    elif camera not in CAMERAS:
        raise DescriptionError(f"{need}, not {camera!r}")
    if distance_reaches is not None:
        distance_reaches = number("distance_reaches", distance_reaches, lambda v: v > 0, "a number > 0 (reaches)")
    if focal_px is not None:
        focal_px = number("focal_px", focal_px, lambda v: v > 0, "a number > 0 (pixels)")
    trajectory = "random" if trajectory is None else trajectory
    if not isinstance(trajectory, str) or trajectory not in TRAJECTORIES:
        raise DescriptionError(f"trajectory must be one of {', '.join(map(repr, TRAJECTORIES))}, not {trajectory!r}")
    if not isinstance(joint_range, str) or joint_range not in JOINT_RANGES:
        raise DescriptionError(f"joint_range must be one of {', '.join(map(repr, JOINT_RANGES))}, not {joint_range!r}")
    full = joint_range == "full"
    try:
        rng = np.random.default_rng(seed)
    except (TypeError, ValueError) as e:
        raise TrackError(f"seed must be None, a non-negative integer or a numpy Generator, "
                         f"not {seed!r} ({e})") from None
    chain = _chain(urdf_or_chain)
    from .views import observe, orbit_cameras

    robot = RobotKinematics(chain.metadata["urdf_path"], chain)
    if trajectory == "random":
        q = random_trajectory(robot, n_frames, fps, rng, full=full)
    elif trajectory == "milling":
        q = milling_trajectory(robot, n_frames, rng, full=full)
    else:
        q = singular_trajectory(robot, n_frames, fps, rng, full=full)
    positions = robot.positions(q)
    elev = rng.uniform(10.0, 35.0) if elevation_deg is None else float(elevation_deg)
    cam_seed = int(rng.integers(2 ** 31))
    if camera not in ("static", "moving"):
        if pinhole_cam is None:
            pinhole_cam = _draw_camera(camera, cam_seed, image_size, focal_px, dist)
        return _film_pinhole(chain, robot, q, positions, rng, elev, cam_seed, pinhole_cam, distance_reaches,
                             image_size, focal_px, dist, noise_px, drop, fps, trajectory)
    unit = orbit_cameras(n_frames, sweep_deg=0.0 if camera == "static" else 10.0, elevation_deg=elev,
                         seed=cam_seed)
    flat = observe(positions, unit)
    extent = max(np.ptp(flat[..., 0]), np.ptp(flat[..., 1]))
    scale = image_height_px / max(extent, 1e-12)
    cameras = unit * scale
    margin = 0.1 * image_height_px
    translations = np.broadcast_to(margin - scale * flat.reshape(-1, 2).min(0), (n_frames, 2)).copy()
    tracks = observe(positions, cameras, translations=translations, noise_px=noise_px,
                     seed=int(rng.integers(2 ** 31)))
    confidence = np.ones(tracks.shape[:2])
    if drop > 0:
        gone = rng.random(confidence.shape) < drop
        tracks[gone] = np.nan
        confidence[gone] = 0.0
    return RobotTrial(chain=chain, q=q, positions=positions, cameras=cameras, translations=translations,
                      tracks=tracks, confidence=confidence, fps=float(fps), urdf_path=chain.metadata["urdf_path"],
                      noise_px=float(noise_px), trajectory=trajectory)


def _draw_camera(kind: str, cam_seed: int, image_size, focal_px, dist):
    """The pinhole camera of ``kind`` ("pinhole": phone or industrial, drawn; "phone"; "industrial"), its
    focal length, size and distortion drawn from ``cam_seed`` unless given (see :func:`synthesize`)."""
    from ..cameras.pinhole import PinholeCamera

    # a generator of its own, so that the camera drawn leaves the trajectory and noise of a seed unchanged
    r = np.random.default_rng([cam_seed, 17])
    if kind == "pinhole":  # a focal given in pixels, without a lens: the phone-like camera it always was
        kind = "phone" if r.random() < 0.5 or focal_px is not None else "industrial"
    if kind == "phone":
        w, h = image_size or (1920, 1080)
        f = r.uniform(0.8, 1.2) * w
        d = None
    else:
        w, h = image_size or INDUSTRIAL_SIZE
        f = r.uniform(6.0, 12.0) / SENSOR_WIDTH_MM * w
        d = (r.uniform(-0.25, -0.05), r.uniform(0.0, 0.08), 0.0, 0.0, 0.0)
    f = f if focal_px is None else focal_px
    d = d if dist is None else dist
    return PinholeCamera(f, f, w / 2, h / 2, d, int(w), int(h))


def _film_pinhole(chain, robot, q, positions, rng, elev, cam_seed, cam, distance_reaches, image_size, focal_px,
                  dist, noise_px, drop, fps, trajectory) -> RobotTrial:
    """One static pinhole camera looking at the centre of the trajectory's points (see synthesize)."""
    from ..cameras.pinhole import PinholeCamera
    from .views import look_rotation

    F = len(q)
    d = rng.uniform(1.5, 4.0) if distance_reaches is None else float(distance_reaches)
    w, h = (float(v) for v in (cam.image_size or image_size or (1920, 1080)))
    cam = PinholeCamera(cam.fx, cam.fy, cam.cx, cam.cy, cam.dist if dist is None else dist, int(w), int(h))
    az = np.random.default_rng(cam_seed).uniform(0, 2 * np.pi)
    R = look_rotation(az, np.deg2rad(elev))
    target = positions.reshape(-1, 3).mean(0)
    reach = robot.reach()
    for _ in range(8 if distance_reaches is None else 1):
        t = -R @ (target - R[2] * d * reach)
        y = positions @ R.T + t
        if distance_reaches is not None or (y[..., 2] <= 0.05 * reach).any():
            if distance_reaches is None:
                d *= 1.5
                continue
            break
        # back off until every point is inside the image (5 % margin), as a camera operator frames a shot
        xy = y[..., :2] / y[..., 2:]
        lens = np.array([cam.fx, cam.fy])
        out = np.abs(xy * lens).max((0, 1)) / (0.45 * np.array([w, h]))
        if out.max() <= 1.0:
            break
        d *= float(out.max()) * 1.02
    if (y[..., 2] <= 0.05 * reach).any():
        raise TrackError("the robot reaches behind or into the pinhole camera: increase distance_reaches")
    clean = cam.project(y)
    tracks = clean + np.random.default_rng(int(rng.integers(2 ** 31))).normal(0, noise_px, clean.shape)
    confidence = np.ones(tracks.shape[:2])
    if drop > 0:
        gone = rng.random(confidence.shape) < drop
        tracks[gone] = np.nan
        confidence[gone] = 0.0
    K = np.asarray(cam.K, float)
    zc = float(y[..., 2].mean())
    cameras = np.broadcast_to(K[0, 0] / zc * R[:2], (F, 2, 3)).copy()
    translations = np.broadcast_to(K[:2, 2] + K[0, 0] / zc * t[:2], (F, 2)).copy()
    return RobotTrial(chain=chain, q=q, positions=positions, cameras=cameras, translations=translations,
                      tracks=tracks, confidence=confidence, fps=float(fps), urdf_path=chain.metadata["urdf_path"],
                      noise_px=float(noise_px), trajectory=trajectory, intrinsics=cam, camera_R=R, camera_t=t,
                      image_size=(int(w), int(h)))


def _chain(urdf_or_chain: Any) -> KinematicChain:
    if isinstance(urdf_or_chain, KinematicChain):
        if not urdf_or_chain.metadata.get("urdf_path"):
            raise DescriptionError(f"chain {urdf_or_chain.name!r} has no URDF (metadata['urdf_path']); make it "
                                   "with chainspace.from_urdf")
        return urdf_or_chain
    from ..io.urdf import from_urdf

    return from_urdf(urdf_or_chain)
