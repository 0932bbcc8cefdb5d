"""Are the fit's standard deviations honest? (issue 21, part 1)

    python benchmarks/bench_uncertainty.py                     # 50 trials, milling arm, 30 frames, 1 px, pinhole camera
    python benchmarks/bench_uncertainty.py --trials 5 --robot ur10
    python benchmarks/bench_uncertainty.py --camera static     # the solver's own weak-perspective model (older rows)
    python benchmarks/bench_uncertainty.py --json u.json       # every trial saved as it comes; run again to resume
    python benchmarks/bench_uncertainty.py --from-json u.json  # the table of the saved trials

Each trial films the robot (chainspace.synthesize: a random smooth motion, Gaussian pixel noise and by
default its realistic static pinhole camera, a phone or an industrial camera with lens distortion,
1.5-4 reaches away: footage more realistic than the fit's model; ``--camera static``: a static
weak-perspective camera, the weak fit's own model), reconstructs, fits the joint angles (defaults:
acceleration prior on; a pinhole trial's fit is given the camera's intrinsics and distortion, as a
calibrated user would) and compares the fitted angles with the truth frame by frame: the share of
true values within one reported standard deviation (``fit.q_std``; target 68 % +- 10 %) and within
two (95 % for a Gaussian), per joint and pooled, per trial and per camera kind. A joint seen only
relative to frame 0 is compared as its change since frame 0.

Every trial counts in every share, whatever it reports: a fit on a wrong branch (a wrist turned half a
turn: its errors lie far outside its deviations) and joints flagged ambiguous included. Such trials
are also counted apart: "off" (a joint more than 5 degrees RMS and more than 5 of its reported
deviations off), and of those, how many had that joint flagged ambiguous (the fit said it did not
know which branch) or not (a silent failure). The std model does not depend on the number of frames,
so 30 frames (half the default of the other robot benchmarks) keep 50 trials affordable.

Why trials differ: a trial's errors are not independent draws. The static camera is shared by all its
frames and the motion prior couples neighbouring ones, so one trial is about one draw of a few
correlated directions, and its share within 1 std scatters widely even when the deviations are
right. The model says how widely: each trial also draws 1,000 error vectors from the fit's full
covariance (:func:`chainspace.robot.uncertainty.joint_covariance`, the camera marginalised, whose
diagonal is q_std) and records where its observed share falls among theirs (a rank, 0-1). Honest
deviations and correlations give ranks spread evenly over 0-1 (about 5 % of trials below 0.05 and 5 %
above 0.95); the chi-square of the errors under that covariance, per degree of freedom, is near 1.
"""

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from unittest import mock

import numpy as np

OFF_DEG, OFF_STD = 5.0, 5.0  # a trial is "off" on a joint beyond both (a branch flip, not noise)


def one_trial(chain, seed: int, n_frames: int, noise_px: float, camera: str = "pinhole") -> dict:
    """One trial: per joint, per frame, whether the truth lies within 1 and 2 reported deviations
    (None where the fit reports no deviation), the joint's RMS error and RMS std, ambiguity."""
    from chainspace.reconstruction.pipeline import reconstruct
    from chainspace.robot import uncertainty
    from chainspace.robot.fit import fit_joint_angles
    from chainspace.synthetic.robot import synthesize

    trial = synthesize(chain, n_frames=n_frames, noise_px=noise_px, seed=seed, camera=camera)
    # a pinhole trial: the calibrated camera (K, distortion) goes to the fit, which then refines a pinhole view
    pinhole = dict(tracks=trial.tracks, intrinsics=trial.intrinsics) if trial.intrinsics is not None else {}
    t0 = time.perf_counter()
    # listen in on the fit's std computation: its inputs give the full covariance, which the fit does not
    # keep (the last call is the reported fit's: with intrinsics the weak start is not assessed)
    with warnings.catch_warnings(), mock.patch.object(uncertainty, "joint_std", wraps=uncertainty.joint_std) as spy:
        warnings.simplefilter("ignore")
        fit = fit_joint_angles(reconstruct(trial.tracks, chain, seed=seed), fps=trial.fps, **pinhole)
    secs = time.perf_counter() - t0
    robot = fit.kinematics()
    d = fit.angles - robot.angles(trial.q)
    d = robot.wrap_angles(d)
    rel = np.asarray(fit.relative, bool)
    d[:, rel] = robot.wrap_angles(d - d[0])[:, rel]
    std = np.asarray(fit.q_std, float)
    judged = (np.asarray(fit.observable, bool) | rel)[None] & np.isfinite(std) & (std > 0)
    unit = np.where(robot.prismatic_v, 1000.0, np.degrees(1.0))
    out = dict(seed=seed, seconds=secs, camera=_camera_kind(trial), joints=list(fit.joint_names), unit=unit.tolist(),
               prismatic=robot.prismatic_v.tolist(), judged=judged.tolist(),
               abs_err=np.abs(d).tolist(), std=np.where(judged, std, np.nan).tolist(),
               ambiguous=np.asarray(fit.ambiguous, bool).tolist())
    if spy.call_args is not None and judged.any() and np.isfinite(fit.noise_px):
        cov = fit.noise_px ** 2 * uncertainty.joint_covariance(*spy.call_args.args, **spy.call_args.kwargs)
        out.update(_model_check(d[judged], std[judged], cov[np.ix_(judged.reshape(-1), judged.reshape(-1))], seed))
    return out


def _camera_kind(trial) -> str:
    """"static" (weak perspective), else "phone" or "industrial" (a distorting lens) and the focal, px."""
    cam = trial.intrinsics
    if cam is None:
        return "static"
    dist = getattr(cam, "dist", None)
    kind = "industrial" if dist is not None and np.any(np.asarray(dist) != 0) else "phone"
    return f"{kind} f={float(cam.K[0, 0]):.0f}"


def _model_check(err: np.ndarray, std: np.ndarray, cov: np.ndarray, seed: int, draws: int = 1000) -> dict:
    """Where a trial's share of errors ``err`` (n,) within one reported deviation ``std`` (n,) falls
    among the shares of ``draws`` error vectors drawn from the full covariance ``cov`` (n, n) (its rank,
    0-1, ties counted half; and the 5, 50, 95 % points of the drawn shares), and the chi-square of err
    under cov per degree of freedom."""
    lam, V = np.linalg.eigh(cov)
    lam = np.maximum(lam, 1e-12 * lam.max())  # a direction of (numerically) zero variance: not a free chi-square
    drawn = (V * np.sqrt(lam)) @ np.random.default_rng(seed).standard_normal((len(lam), draws))
    shares = (np.abs(drawn) <= std[:, None]).mean(0)
    share = float((np.abs(err) <= std).mean())
    z = V.T @ err / np.sqrt(lam)
    return dict(model_rank=float((shares < share).mean() + 0.5 * (shares == share).mean()),
                model_shares=np.percentile(shares, [5, 50, 95]).tolist(), chi2_dof=float(z @ z / len(err)))


def summarise(trials: list[dict]) -> dict:
    """Pooled and per-trial shares within 1 and 2 std, per joint rows, and the off/ambiguous counts."""
    names, unit = trials[0]["joints"], np.asarray(trials[0]["unit"])
    per_trial, i1s, i2s, e2s, s2s, off, off_flagged = [], [], [], [], [], 0, 0
    warnings.simplefilter("ignore", RuntimeWarning)  # a joint never judged in a trial: its means are NaN, as meant
    for t in trials:
        judged = np.asarray(t["judged"], bool)
        e, s = np.asarray(t["abs_err"], float), np.asarray(t["std"], float)
        i1, i2 = np.where(judged, e <= s, np.nan), np.where(judged, e <= 2 * s, np.nan)
        i1s.append(i1), i2s.append(i2), e2s.append(np.where(judged, e ** 2, np.nan)), s2s.append(s ** 2)
        rms_e = np.sqrt(np.nanmean(np.where(judged, e ** 2, np.nan), 0)) * unit
        rms_s = np.sqrt(np.nanmean(s ** 2, 0)) * unit
        bad = (rms_e > OFF_DEG) & (rms_e > OFF_STD * rms_s)
        amb = np.asarray(t["ambiguous"], bool)
        off += bool(bad.any())
        off_flagged += bool(bad.any() and amb[bad].all())
        per_trial.append(dict(seed=t["seed"], within1=float(np.nanmean(i1)), off=[names[k] for k in np.flatnonzero(bad)],
                              ambiguous=[names[k] for k in np.flatnonzero(amb)], seconds=t["seconds"]))
    i1, i2 = np.concatenate(i1s), np.concatenate(i2s)
    e, s = np.concatenate(e2s), np.concatenate(s2s)
    prismatic = np.asarray(trials[0]["prismatic"], bool)
    rows = [dict(joint=n, within1=np.nanmean(i1[:, k]), within2=np.nanmean(i2[:, k]),
                 rms_err=np.sqrt(np.nanmean(e[:, k])) * unit[k], rms_std=np.sqrt(np.nanmean(s[:, k])) * unit[k],
                 unit="mm" if prismatic[k] else "deg")
            for k, n in enumerate(names) if np.isfinite(i1[:, k]).any()]
    w1 = np.array([p["within1"] for p in per_trial])
    checked = [t for t in trials if "model_rank" in t]  # trials saved before the check have none
    model = None if not checked else dict(
        n=len(checked), rank=np.array([t["model_rank"] for t in checked]),
        band=np.array([t["model_shares"] for t in checked]),
        chi2=np.array([t["chi2_dof"] for t in checked]),
        flipped=np.array([bool(p["off"]) for t, p in zip(trials, per_trial) if "model_rank" in t]))
    kinds = [t.get("camera", "static").split()[0] for t in trials]  # phone, industrial (distorting) or static

    def share(within, kind):
        return float(np.nanmean(np.concatenate([a for a, b in zip(within, kinds) if b == kind])))

    by_camera = {k: dict(n=kinds.count(k), within1=share(i1s, k), within2=share(i2s, k)) for k in sorted(set(kinds))}
    return dict(rows=rows, within1=float(np.nanmean(i1)), within2=float(np.nanmean(i2)), per_trial=per_trial,
                by_camera=by_camera,
                trial_within1=w1, off=off, off_flagged=off_flagged, model=model,
                ambiguous_trials=sum(bool(p["ambiguous"]) for p in per_trial),
                seconds=float(sum(t["seconds"] for t in trials)))


CAMERAS = {"pinhole": "a static pinhole camera (synthesize's default: phone or industrial with distortion, "
                      "1.5-4 reaches; the fit given its intrinsics)",
           "static": "a static weak-perspective camera (the weak fit's own model)"}


def table(res: dict, robot: str, n_frames: int, noise_px: float, camera: str = "pinhole") -> str:
    w1 = res["trial_within1"]
    n = len(w1)
    out = [f"Uncertainty honesty: {robot}, {n} trials x {n_frames} frames, {CAMERAS[camera]}, {noise_px:g} px noise; "
           f"{res['seconds']:.0f} s of fitting ({res['seconds'] / max(n, 1):.0f} s a trial). Every trial counts.", "",
           "| joint | within 1 std % (target 68 +- 10) | within 2 std % (95) | RMS error | RMS reported std |",
           "|---|---|---|---|---|"]
    for r in res["rows"]:
        out.append(f"| {r['joint']} | {100 * r['within1']:.1f} | {100 * r['within2']:.1f} | "
                   f"{r['rms_err']:.3f} {r['unit']} | {r['rms_std']:.3f} {r['unit']} |")
    out.append(f"| **pooled** | **{100 * res['within1']:.1f}** | **{100 * res['within2']:.1f}** | | |")
    inside = int(((w1 >= 0.58) & (w1 <= 0.78)).sum())
    out += ["", f"Per trial, within 1 std: median {100 * np.median(w1):.1f} %, quartiles {100 * np.percentile(w1, 25):.1f}"
            f"-{100 * np.percentile(w1, 75):.1f} %, range {100 * w1.min():.1f}-{100 * w1.max():.1f} %; {inside} of {n} "
            "trials in 58-78 %.",
            f"Trials with a joint off by more than {OFF_DEG:g} deg RMS and {OFF_STD:g} of its reported std (a branch "
            f"flip): {res['off']}, of which flagged ambiguous on every such joint: {res['off_flagged']}, silent: "
            f"{res['off'] - res['off_flagged']}. Trials with any joint flagged ambiguous: {res['ambiguous_trials']}.",
            *([] if len(res["by_camera"]) < 2 else [
                "By camera: " + "; ".join(f"{k} ({c['n']} trials) {100 * c['within1']:.1f} % within 1 std, "
                                          f"{100 * c['within2']:.1f} % within 2" for k, c in res["by_camera"].items())
                + " (industrial: a lens with barrel distortion, given to the fit)."]),
            *_model_lines(res["model"]),
            "", "Per trial (seed: % within 1 std; joints off; joints flagged ambiguous):",
            "; ".join(f"{p['seed']}: {100 * p['within1']:.0f}" + (f" (off: {', '.join(p['off'])})" if p['off'] else "")
                      + (f" [ambiguous: {', '.join(p['ambiguous'])}]" if p['ambiguous'] else "")
                      for p in res["per_trial"])]
    return "\n".join(out)


def _model_lines(m: dict | None) -> list[str]:
    """The spread of the per-trial shares against the model's own (see the module docstring)."""
    if m is None:
        return []
    rank, ok = m["rank"], ~m["flipped"]
    return ["", f"Is the spread between trials the model's? ({m['n']} trials checked against draws from each "
                f"trial's full covariance): the model puts a trial's share within 1 std between "
                f"{100 * np.median(m['band'][:, 0]):.0f} and {100 * np.median(m['band'][:, 2]):.0f} % (5-95 %, "
                f"median over trials); observed shares below the model's 5 %: {int((rank < 0.05).sum())}, above its "
                f"95 %: {int((rank > 0.95).sum())} of {m['n']} (about {0.05 * m['n']:.1f} each if honest); ranks' "
                f"quartiles {np.percentile(rank, 25):.2f}, {np.median(rank):.2f}, {np.percentile(rank, 75):.2f} "
                "(0.25, 0.50, 0.75 if honest). Chi-square per degree of freedom of the errors under the full "
                f"covariance: median {np.median(m['chi2'][ok] if ok.any() else m['chi2']):.2f}"
                + (f" over the {int(ok.sum())} trials without a flip (1 if honest)" if ok.any() else "") + "."]


def _setting(trial: dict) -> list | None:
    """A saved trial's [robot, frames, noise, camera]; trials saved before --camera were weak perspective."""
    s = trial.get("setting")
    return s + ["static"] if isinstance(s, list) and len(s) == 3 else s


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=50)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--robot", default="milling arm", help="a benchmark robot (bench_robots) or an example-robot-data name")
    p.add_argument("--noise", type=float, default=1.0, help="pixel noise per coordinate")
    p.add_argument("--camera", choices=list(CAMERAS), default="pinhole",
                   help="pinhole: synthesize's realistic static camera, the fit given its intrinsics (default); "
                        "static: weak perspective, the solver's own model (the rows before the pinhole ones)")
    p.add_argument("--max-minutes", type=float, default=float("inf"),
                   help="stop starting trials after this long (the table counts the trials that ran, and says so)")
    p.add_argument("--json", default=None, help="save every trial here as it comes; trials already in it are not "
                                                 "run again (resume)")
    p.add_argument("--from-json", nargs="+", default=None, help="print the table of trials saved with --json")
    p.add_argument("--quick", action="store_true", help="2 trials of the double pendulum, 10 frames (a smoke run)")
    a = p.parse_args(argv)
    if a.quick:
        a.trials, a.frames, a.robot = 2, 10, "double_pendulum"
    if a.trials < 1 or a.frames < 3 or not a.noise > 0:
        p.error("--trials >= 1, --frames >= 3 and --noise > 0 are needed")
    if a.from_json:
        trials = [t for f in a.from_json for t in json.loads(Path(f).read_text())]
        if any(_setting(t) != _setting(trials[0]) for t in trials):
            p.error("the files hold trials of different robots, frame counts, noises or cameras: one table each")
        a.robot, a.frames, a.noise, a.camera = _setting(trials[0])
    else:
        from chainspace.bench.robots import ROBOTS, robot_chain
        from chainspace.io.descriptions import example_robot_urdf
        from chainspace.io.results import atomic_write
        from chainspace.io.urdf import from_urdf

        chain = robot_chain(a.robot) if a.robot in ROBOTS else from_urdf(example_robot_urdf(a.robot))
        path = Path(a.json) if a.json else None
        trials = json.loads(path.read_text()) if path and path.exists() else []
        setting = [a.robot, a.frames, a.noise, a.camera]
        if any(_setting(t) != setting for t in trials):
            p.error(f"{path} holds trials of another robot, frame count, noise or camera (or is no file of this "
                    "benchmark)")
        start = time.perf_counter()
        for seed in range(a.trials):
            if any(t["seed"] == seed for t in trials):
                continue
            if time.perf_counter() - start > 60 * a.max_minutes:
                print(f"stopped after {a.max_minutes:g} minutes: {len(trials)} of {a.trials} trials ran",
                      file=sys.stderr)
                break
            trials.append(dict(one_trial(chain, seed, a.frames, a.noise, a.camera), setting=setting))
            w1 = np.nanmean(np.where(trials[-1]["judged"], np.asarray(trials[-1]["abs_err"]) <= trials[-1]["std"], np.nan))
            print(f"trial {seed + 1}/{a.trials}: within 1 std {100 * w1:.0f} %, ambiguous: "
                  f"{[n for n, b in zip(trials[-1]['joints'], trials[-1]['ambiguous']) if b]}, "
                  f"{trials[-1]['seconds']:.0f} s ({trials[-1]['camera']})", file=sys.stderr, flush=True)
            if path:
                with atomic_write(path, overwrite=True) as fh:  # our own file, rewritten with each trial
                    fh.write(json.dumps(trials, default=float))
    print(table(summarise(trials), a.robot, a.frames, a.noise, a.camera))
    return 0


if __name__ == "__main__":
    sys.exit(main())
