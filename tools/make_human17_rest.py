"""Derive the rest pose of robots/human17.toml from CMU walks of subjects 02, 07 and 16.

Subject 35 is left out on purpose: the benchmark evaluates its walks, and the initial pose must not
come from the evaluated subject.

Steps (all Z-up metres, via chainspace.io.datasets):
1. every walk trial of subjects 02, 07, 16 in ../shared/data/cmu -> human17 poses (F, 17, 3);
2. each frame root-centred (pelvis at the origin) and turned about the vertical so that the body faces
   +x, the facing taken from the hips (left hip - right hip, horizontal, points to +y);
3. the mean of the frames of each subject, then the mean over subjects (each subject weighs the same);
4. bone directions from that mean pose, bone lengths = mean per-frame bone lengths (averaging positions
   of swinging limbs shortens them; lengths are what the reconstruction keeps);
5. made left/right symmetric: averaged with its mirror image (y -> -y, left <-> right).

Run:  .venv/bin/python tools/make_human17_rest.py [--check]   (--check: compare, do not write)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from chainspace.chain import KinematicChain
from chainspace.io.datasets import HUMAN17_BONES, HUMAN17_JOINTS, cmu_positions, cmu_to_human17, cmu_trials
from chainspace.io.skeleton_file import save_skeleton_file

SUBJECTS = ("02", "07", "16")
OUT = Path(__file__).resolve().parents[1] / "robots" / "human17.toml"
J = {n: i for i, n in enumerate(HUMAN17_JOINTS)}


def facing_frames(poses: np.ndarray) -> np.ndarray:
    """Root-centre each frame and turn it about z so that left hip - right hip points to +y."""
    P = poses - poses[:, [J["pelvis"]]]
    h = P[:, J["left_hip"], :2] - P[:, J["right_hip"], :2]
    ang = np.arctan2(h[:, 1], h[:, 0]) - np.pi / 2  # rotate by -ang to bring h onto +y
    c, s = np.cos(-ang), np.sin(-ang)
    R = np.zeros((len(P), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return np.einsum("fij,fkj->fki", R, P)


def mirror(pose: np.ndarray) -> np.ndarray:
    """The mirror image (y -> -y) with left and right joints swapped."""
    swap = [J[n.replace("left_", "R_").replace("right_", "left_").replace("R_", "right_")] for n in HUMAN17_JOINTS]
    m = pose[swap].copy()
    m[:, 1] *= -1
    return m


def build() -> tuple[KinematicChain, list[str]]:
    chain = KinematicChain(HUMAN17_JOINTS, HUMAN17_BONES, name="human17")
    means, lengths, used = [], [], []
    for sub in SUBJECTS:
        trials = cmu_trials(sub)
        if not trials:
            sys.exit(f"no CMU trials of subject {sub} in the shared data")
        frames = []
        for asf, amc in trials:
            c31, p31 = cmu_positions(asf, amc)
            frames.append(facing_frames(cmu_to_human17(p31, c31)))
            used.append(amc.stem)
        P = np.concatenate(frames)
        means.append(P.mean(axis=0))
        lengths.append(chain.bone_lengths(P).mean(axis=0))
    mean = np.mean(means, axis=0)
    mean = (mean + mirror(mean)) / 2
    B = chain.bone_vectors(mean)
    length = np.mean(lengths, axis=0)
    # Symmetric lengths: average each left bone with its right twin.
    names = [b[1] for b in chain.bones]
    twin = [names.index(n.replace("left_", "R_").replace("right_", "left_").replace("R_", "right_")) for n in names]
    length = (length + length[twin]) / 2
    B = B / np.linalg.norm(B, axis=1, keepdims=True) * length[:, None]
    rest = chain.poses_from_bones(B)
    rest = (rest + mirror(rest)) / 2  # removes rounding asymmetry only
    print(f"{len(used)} trials: {', '.join(used)}")
    return chain.with_rest_pose(rest), used


def main() -> None:
    chain, used = build()
    desc = (
        "Human 17-joint skeleton (H36M-style joint set), Z-up metres, facing +x, pelvis at the origin. "
        "Rest pose: mean pose of the CMU walks of subjects 02, 07 and 16 (" + ", ".join(used) + "), "
        "root-centred and turned to face +x per frame, bone lengths = mean bone lengths, made left/right "
        "symmetric; derived by tools/make_human17_rest.py. CMU points: see chainspace.io.datasets."
    )
    src = ("CMU Graphics Lab Motion Capture Database, http://mocap.cs.cmu.edu (created with funding from "
           "NSF EIA-0196217)")
    if "--check" in sys.argv:
        from chainspace.io.skeleton_file import from_skeleton_file

        old = from_skeleton_file(OUT).rest_pose
        print("max difference to the shipped file (m):", np.abs(old - chain.rest_pose).max())
        return
    chain.metadata.clear()
    save_skeleton_file(chain, OUT, overwrite=True, description=desc, source=src)
    print(f"wrote {OUT}")
    for n, p in zip(chain.joints, chain.rest_pose):
        print(f"  {n:15s} {p.round(3)}")


if __name__ == "__main__":
    main()
