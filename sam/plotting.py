"""Figures of recordings (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backend_bases import FigureCanvasBase  # noqa: E402

from .recording import Recording  # noqa: E402

MPA = 1e6


def figure_suffixes() -> tuple[str, ...]:
    """File name endings matplotlib can save a figure as (".png", ".pdf", ".svg", ...)."""
    return tuple(sorted("." + ext for ext in FigureCanvasBase.get_supported_filetypes()))


def velocity_of(rec: Recording) -> tuple[np.ndarray, str]:
    """Measured velocity, else the true one, else a finite difference of x (labelled so)."""
    if rec.has("v"):
        return rec.signals["v"], "v"
    if "true_v" in rec.truth:
        return rec.truth["true_v"], "v (true)"
    return np.gradient(rec.signals["x"], rec.t), "dx/dt"


def plot_recordings(recs: dict[str, Recording], path: str | Path, title: str = "") -> Path:
    """u, x (or theta), v, p_A and p_B against time, one line per recording; saved as PNG."""
    fig, axes = plt.subplots(5, 1, figsize=(8, 10), sharex=True)
    for label, rec in recs.items():
        pos, pos_label = (rec.signals["x"], "x [m]") if rec.has("x") else (rec.signals["theta"], "theta [rad]")
        v, v_label = velocity_of(rec)
        rows = [(rec.signals["u"], "u [V]"), (pos, pos_label), (v, f"{v_label} [m/s]"),
                (rec.signals["pA"] / MPA, "p_A [MPa]"), (rec.signals["pB"] / MPA, "p_B [MPa]")]
        for ax, (y, ylabel) in zip(axes, rows):
            ax.plot(rec.t, y, lw=0.8, label=label)
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    if len(recs) > 1:
        axes[0].legend(loc="best", fontsize="small")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
