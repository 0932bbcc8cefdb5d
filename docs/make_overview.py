"""Make docs/_static/overview.png, the picture of the README and the docs' front page.

    .venv/bin/python docs/make_overview.py

The shipped milling arm filmed in simulation (60 frames, 1 px noise, the tool tracing a milling
contour), reconstructed from its 2D tracks and fitted with its URDF, as in the README's tour. Left:
the tracks and the fitted robot drawn over them in the image; right: the fitted robot in 3D.
"""

from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import chainspace as cs  # noqa: E402

OUT = Path(__file__).resolve().parent / "_static" / "overview.png"

arm = cs.shipped("milling_arm")
trial = cs.synthesize(arm, n_frames=60, noise_px=1.0, trajectory="milling", seed=4, camera="static")  # the demo's camera
rec = cs.reconstruct(trial.tracks, arm, confidence=trial.confidence, seed=0)
fit = cs.fit_joint_angles(rec)
report = cs.validate(fit, truth_q=trial.q)
print(report.table())

robot = cs.point_positions(arm, fit.q)  # (F, J, 3) metres, the robot's base frame
# The first joint is seen relative to frame 0 (a static camera): turn the truth by its frame-0 offset.
q_true = trial.q.copy()
q_true[:, 0] += fit.q[0, 0] - trial.q[0, 0]
truth = cs.point_positions(arm, q_true)
image = np.einsum("fij,fkj->fki", fit.cameras, robot) + fit.translations_2d[:, None, :]
shown = np.linspace(0, len(robot) - 1, 5).astype(int)
bones = [(arm.joint_index(a), arm.joint_index(b)) for a, b in arm.bones]
tip = arm.joint_index("tool_tip")

fig = plt.figure(figsize=(9.0, 4.2), dpi=100)
grid = fig.add_gridspec(1, 2, width_ratios=[1, 1.4])
ax = fig.add_subplot(grid[0])
for f in shown:
    for a, b in bones:
        ax.plot(image[f, [a, b], 0], image[f, [a, b], 1], "-", color="tab:blue", lw=2, alpha=0.35 + 0.13 * list(shown).index(f))
ax.plot(trial.tracks[:, :, 0].ravel(), trial.tracks[:, :, 1].ravel(), ".", ms=2, color="tab:orange", label="2D tracks (1 px noise)")
ax.plot([], [], "-", color="tab:blue", lw=2, label="fitted robot, reprojected")
ax.set_aspect("equal")
ax.invert_yaxis()
ax.set_xlabel("x (px)")
ax.set_ylabel("y (px)")
ax.set_title("one camera: tracks and fit", fontsize=10)
ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), fontsize=8)

ax3 = fig.add_subplot(grid[1], projection="3d")
for f in shown:
    for a, b in bones:
        ax3.plot(*robot[f, [a, b]].T, "-", color="tab:blue", lw=2, alpha=0.35 + 0.13 * list(shown).index(f))
ax3.plot(*truth[:, tip].T, "-", color="k", lw=1, label="true tool path")
ax3.plot(*robot[:, tip].T, "--", color="tab:red", lw=1, label="fitted tool path")
ax3.set_xlabel("x (m)")
ax3.set_ylabel("y (m)")
ax3.set_zlabel("z (m)")
ax3.set_box_aspect(np.maximum(np.ptp(robot.reshape(-1, 3), axis=0), 1.0))
ax3.view_init(elev=20, azim=-60)
ax3.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(3))
ax3.set_title("joint angles fitted to the URDF (3D)", fontsize=10)
ax3.legend(loc="upper left", fontsize=8, bbox_to_anchor=(0.0, 0.95))
fig.suptitle(f"chainspace: the milling arm from one camera, 60 frames; fitted robot 3D error {report.error_3d_mm:.1f} mm",
             fontsize=11)
fig.tight_layout()
fig.savefig(OUT, dpi=100)
print(OUT, OUT.stat().st_size, "bytes")
