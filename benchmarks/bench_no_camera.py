"""Close-range footage fitted without its camera: does the weak-perspective fit say it is wrong? (issues 17, 21)

    python benchmarks/bench_no_camera.py                  # 5 robots x 3 seeds, 60 frames, 1 px
    python benchmarks/bench_no_camera.py --quick          # the milling arm, one seed, 30 frames
    python benchmarks/bench_no_camera.py --robots UR10 --seeds 5
    python benchmarks/bench_no_camera.py --first-seed 3     # seeds 3-5: not used to set the threshold

A user who does not know the camera fits the tracks with ``fit_joint_angles(rec)``: weak perspective.
Each run films the robot with ``chainspace.synthesize``'s default camera (a phone or an industrial lens
1.5-4 reaches away, some with lens distortion: perspective the fit does not model), reconstructs and
fits without intrinsics or image size, and judges every joint as the full-range benchmark does
(:func:`chainspace.bench.full_range.judge_joints`): "ok" within 2 degrees RMS, else "flagged" when the
fit reports the joint not observable, ambiguous, poorly fitted or uncertain, else "silent". Every run is
counted. Also printed: the typical point's misfit against the tracks' own jitter
(:func:`chainspace.robot.uncertainty.camera_misfit`, about 0.9 when the model matches).
"""

import argparse
import sys
import warnings

import numpy as np

ROBOTS = ["milling arm", "UR10", "Panda", "xArm7", "Kinova"]


def run(name: str, seed: int, n_frames: int) -> dict:
    from chainspace.bench.full_range import judge_joints
    from chainspace.bench.robots import robot_chain
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.robot import uncertainty
    from chainspace.synthetic.robot import synthesize

    chain = robot_chain(name)
    trial = synthesize(chain, n_frames=n_frames, noise_px=1.0, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = fit_joint_angles(reconstruct(trial.tracks, chain, seed=seed))
    joints = judge_joints(fit, trial)
    w = np.isfinite(trial.tracks).all(-1).astype(float)
    rn = np.linalg.norm(fit.reprojected() - trial.tracks, axis=-1)
    # (NaN on builds before camera_misfit, so that they can be run for comparison)
    misfit = uncertainty.camera_misfit(rn, w, uncertainty.track_jitter(trial.tracks, w))[0] \
        if hasattr(uncertainty, "camera_misfit") else float("nan")
    count = {v: sum(j["verdict"] == v for j in joints) for v in ("ok", "flagged", "silent")}
    worst = max(joints, key=lambda j: j["error"])
    silent = [j for j in joints if j["verdict"] == "silent"]
    return dict(robot=name, seed=seed, misfit=misfit, **count, worst=f"{worst['name']} {worst['error']:.1f}",
                worst_silent=max((j["error"] for j in silent), default=0.0))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", nargs="+", default=ROBOTS)
    p.add_argument("--seeds", type=int, default=3, help="N seeds per robot (from --first-seed)")
    p.add_argument("--first-seed", type=int, default=0, help="the first seed (0; 3 for seeds not tuned on)")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--quick", action="store_true", help="the milling arm, one seed, 30 frames (a smoke run)")
    a = p.parse_args(argv)
    if a.quick:
        a.robots, a.seeds, a.frames = ["milling arm"], 1, 30
    print("| robot | seed | misfit / jitter | joints ok | flagged | **silent** | worst joint (deg or mm) | worst silent |")
    print("|---|---:|---:|---:|---:|---:|---|---:|")
    rows = []
    for name in a.robots:
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            r = run(name, seed, a.frames)
            rows.append(r)
            print(f"| {r['robot']} | {r['seed']} | {r['misfit']:.2f} | {r['ok']} | {r['flagged']} | **{r['silent']}** "
                  f"| {r['worst']} | {r['worst_silent']:.1f} |", flush=True)
    n_silent = sum(r["silent"] > 0 for r in rows)
    print(f"\n{len(rows)} runs, {a.frames} frames, 1 px, synthesize's default pinhole camera fitted without it; "
          f"runs with a silent joint: {n_silent}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
