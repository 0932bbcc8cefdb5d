"""The milling arm: film it (synthetic), reconstruct from the 2D tracks, fit its joint angles, validate.

    python examples/milling_arm.py
"""

import chainspace as cs

chain = cs.from_urdf(cs.shipped_path("milling_arm"))  # points: link origins + spindle + tool tip
trial = cs.synthesize(chain, n_frames=150, noise_px=1.0, trajectory="milling", seed=0, camera="static")

rec = cs.reconstruct(trial.tracks, chain)  # 3D from the tracks alone (one uncalibrated camera)
fit = cs.fit_joint_angles(rec)  # URDF fitted in 3D, then refined on the tracks (static camera)
print(fit.message)
print(cs.validate(fit, trial.q).table())
