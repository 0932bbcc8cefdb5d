"""Franka Panda (example-robot-data), tracked without its fingers: the flange joint (its axis runs
through the last tracked points) and the fingers are then not observable, and are reported so.

    python examples/panda.py
"""

import chainspace as cs
from chainspace.io.descriptions import example_robot_urdf

links = ["panda_link0", "panda_link1", "panda_link3", "panda_link4", "panda_link5", "panda_link7",
         "panda_link8", "panda_hand_tcp"]
chain = cs.from_urdf(example_robot_urdf("panda"), links=links)
trial = cs.synthesize(chain, n_frames=150, noise_px=1.0, seed=2, camera="static")

fit = cs.fit_joint_angles(cs.reconstruct(trial.tracks, chain))
print(fit.message)
print(cs.validate(fit, trial.q).table())
