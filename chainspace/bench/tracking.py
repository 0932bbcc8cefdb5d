"""Figures shared by the tracking and video benchmarks."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np


def plot_track_errors(panels: Sequence[tuple[str, Sequence[str], np.ndarray, Sequence[int]]], path: Path) -> None:
    """Tracking error against the truth over the frames: one panel per ``(title, names, err, keyframes)``,
    ``err`` (F, J) px with NaN where a point is lost or not judged (a gap), key frames dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 2.2 * len(panels)), squeeze=False, sharex=True)
    for ax, (title, names, err, anchors) in zip(axes[:, 0], panels, strict=True):
        for j, name in enumerate(names):
            ax.plot(err[:, j], lw=1, label=name)
        for f in anchors:
            ax.axvline(f, color="grey", ls=":", lw=1)
        ax.set_ylabel("error (px)")
        ax.set_title(f"{title} (dotted: key frames; a gap: lost)", fontsize=9)
    axes[-1, 0].set_xlabel("frame")
    axes[0, 0].legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
