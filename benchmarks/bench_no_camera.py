"""Close-range footage fitted without its camera: does the weak-perspective fit say it is wrong? (issues 17, 21)

    python benchmarks/bench_no_camera.py                  # 5 robots x 3 seeds, 60 frames, 1 px
    python benchmarks/bench_no_camera.py --quick          # the milling arm, one seed, 30 frames
    python benchmarks/bench_no_camera.py --robots UR10 --seeds 5
    python benchmarks/bench_no_camera.py --first-seed 3     # seeds 3-5: not used to set the threshold
    python benchmarks/bench_no_camera.py --image-size unknown  # fit_joint_angles(rec, perspective=True)
    python benchmarks/bench_no_camera.py --image-size tracks --centre-offset 400 250

``--image-size unknown`` fits a pinhole camera of unknown focal length and principal point
(``perspective=True``); ``true`` gives the fit the image size (focal length estimated, principal
point at the image centre); ``tracks`` gives it the size whose centre is the centre of the tracks'
extent shifted by ``--centre-offset`` px: a user who guesses the principal point. Every track is
shifted by ``--shift`` px before anything is fitted (a robot filmed off the image centre; the
truth's principal point moves alike).

A user who does not know the camera fits the tracks with ``fit_joint_angles(rec)``: weak perspective.
Each run films the robot with ``chainspace.synthesize``'s default camera (a phone or an industrial lens
1.5-4 reaches away, some with lens distortion: perspective the fit does not model), reconstructs and
fits without intrinsics or image size, and judges every joint as the full-range benchmark does
(:func:`chainspace.bench.full_range.judge_joints`): "ok" within 2 degrees RMS, else "flagged" when the
fit reports the joint not observable, ambiguous, poorly fitted or uncertain, else "silent". Every run is
counted. Also printed: the typical point's misfit against the tracks' own jitter
(:func:`chainspace.robot.uncertainty.camera_misfit`, about 0.9 when the model matches), and for a fit
that reports a pinhole camera how far its principal point lies from the true one (nan: a weak fit).
"""

import argparse
import sys
import warnings

import numpy as np

ROBOTS = ["milling arm", "UR10", "Panda", "xArm7", "Kinova"]


def run(name: str, seed: int, n_frames: int, image_size: str = "none",
        centre_offset: tuple[float, float] = (0.0, 0.0), shift: tuple[float, float] = (0.0, 0.0)) -> dict:
    from chainspace.bench.full_range import judge_joints
    from chainspace.bench.robots import robot_chain
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.robot import uncertainty
    from chainspace.synthetic.robot import synthesize

    chain = robot_chain(name)
    trial = synthesize(chain, n_frames=n_frames, noise_px=1.0, seed=seed)
    trial.tracks = trial.tracks + np.asarray(shift, float)
    kw = {}
    if image_size == "unknown":
        kw["perspective"] = True
    elif image_size == "true":
        kw["image_size"] = tuple(np.asarray(trial.image_size) + 2 * np.asarray(shift, float))
    elif image_size == "tracks":
        seen = np.isfinite(trial.tracks).all(-1)
        centre = 0.5 * (trial.tracks[seen].min(0) + trial.tracks[seen].max(0)) + np.asarray(centre_offset, float)
        kw["image_size"] = tuple(2.0 * centre)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_joint_angles(reconstruct(trial.tracks, chain, seed=seed), **kw)
    joints = judge_joints(fit, trial)
    w = np.isfinite(trial.tracks).all(-1).astype(float)
    rn = np.linalg.norm(fit.reprojected() - trial.tracks, axis=-1)
    # (NaN on builds before camera_misfit, so that they can be run for comparison)
    misfit = uncertainty.camera_misfit(rn, w, uncertainty.track_jitter(trial.tracks, w))[0] \
        if hasattr(uncertainty, "camera_misfit") else float("nan")
    # how far the fitted principal point lies from the truth's (moved with the tracks), px
    fitted_c = getattr(fit, "intrinsics", None)
    c_off = float(np.linalg.norm(fitted_c.K[:2, 2] - trial.intrinsics.K[:2, 2] - np.asarray(shift, float))) \
        if fitted_c is not None and trial.intrinsics is not None else float("nan")
    count = {v: sum(j["verdict"] == v for j in joints) for v in ("ok", "flagged", "silent")}
    worst = max(joints, key=lambda j: j["error"])
    silent = [j for j in joints if j["verdict"] == "silent"]
    return dict(robot=name, seed=seed, misfit=misfit, c_off=c_off, **count, worst=f"{worst['name']} {worst['error']:.1f}",
                worst_silent=max((j["error"] for j in silent), default=0.0))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", nargs="+", default=ROBOTS)
    p.add_argument("--seeds", type=int, default=3, help="N seeds per robot (from --first-seed)")
    p.add_argument("--first-seed", type=int, default=0, help="the first seed (0; 3 for seeds not tuned on)")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--image-size", choices=["none", "unknown", "true", "tracks"], default="none",
                   help="what the fit is told of the image: nothing (default: weak perspective), nothing but "
                        "perspective=True, its true size, or a size centred on the tracks (the principal point "
                        "guessed at their centre)")
    p.add_argument("--shift", type=float, nargs=2, default=(0.0, 0.0), metavar=("DX", "DY"),
                   help="shift every track by this many px first (the robot off the image centre)")
    p.add_argument("--centre-offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("DX", "DY"),
                   help="with --image-size tracks: shift the guessed principal point by this many px")
    p.add_argument("--quick", action="store_true", help="the milling arm, one seed, 30 frames (a smoke run)")
    a = p.parse_args(argv)
    if a.quick:
        a.robots, a.seeds, a.frames = ["milling arm"], 1, 30
    print("| robot | seed | misfit / jitter | joints ok | flagged | **silent** | worst joint (deg or mm) | worst silent "
          "| principal point off (px) |")
    print("|---|---:|---:|---:|---:|---:|---|---:|---:|")
    rows = []
    for name in a.robots:
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            r = run(name, seed, a.frames, a.image_size, tuple(a.centre_offset), tuple(a.shift))
            rows.append(r)
            print(f"| {r['robot']} | {r['seed']} | {r['misfit']:.2f} | {r['ok']} | {r['flagged']} | **{r['silent']}** "
                  f"| {r['worst']} | {r['worst_silent']:.1f} | {r['c_off']:.0f} |", flush=True)
    n_silent = sum(r["silent"] > 0 for r in rows)
    told = {"none": "fitted without it", "true": "fitted with the image size (focal estimated)",
            "unknown": "fitted as a pinhole camera of unknown focal and principal point (perspective=True)",
            "tracks": f"fitted with the principal point guessed at the tracks' centre + {tuple(a.centre_offset)} px "
                      "(focal estimated)"}[a.image_size]
    shifted = f", tracks shifted by {tuple(a.shift)} px" if any(a.shift) else ""
    print(f"\n{len(rows)} runs, {a.frames} frames, 1 px, synthesize's default pinhole camera {told}{shifted}; "
          f"runs with a silent joint: {n_silent}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
