"""UR10 (example-robot-data): check a camera set-up before filming.

Its tool flange joint (wrist_3_joint) turns about the axis through the flange's origin, so with the link
origins alone it would be reported as not observable: the tracked tool point ``tool_mark``, off that
axis, makes it observable. The first joint is seen relative to the first frame only (no tracked point
on the base off its axis).

    python examples/ur10.py
"""

import chainspace as cs
from chainspace.io.descriptions import example_robot_urdf

urdf = example_robot_urdf("ur10")
chain = cs.from_urdf(urdf, extra_frames={"tool_mark": ("tool0", [0.0, 0.08, 0.05])})
trial = cs.synthesize(chain, n_frames=150, noise_px=1.0, seed=1, camera="static")

fit = cs.fit_joint_angles(cs.reconstruct(trial.tracks, chain))
report = cs.validate(fit, trial.q, thresholds={"joint_rms_deg": 1.0})
print(fit.message)
print(report.table())
