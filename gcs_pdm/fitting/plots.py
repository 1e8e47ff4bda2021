"""Predicted versus measured voltage and temperature of one flight (the paper's Figures 3 and 4).

Each panel shows the measurements, the learned model's prediction (its variant named: extended or
paper) and the reference set's (a paper-variant set), so an extended fit is seen beside the paper's
model on the same flight."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; never a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_flight(pred, path: str | Path, reference: str = "reference") -> Path:
    """PNG with one panel per measured quantity: measured, learned prediction, reference prediction."""
    panels = []
    if pred.measured_voltage is not None:
        panels.append(("Terminal voltage [V]", pred.measured_voltage, pred.predicted_voltage, pred.reference_voltage))
    panels.append(("Temperature [°C]", pred.measured_temperature, pred.predicted_temperature, pred.reference_temperature))
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.2 * len(panels)), sharex=True, squeeze=False)
    t_min = (np.asarray(pred.time_s) - pred.time_s[0]) / 60.0
    for ax, (label, meas, learned, ref) in zip(axes[:, 0], panels):
        ax.plot(t_min, meas, ".", ms=2, color="0.4", label="measured")
        model = getattr(pred, "model", "paper")
        ref_model = getattr(pred, "reference_model", "paper")
        ax.plot(t_min, learned, "-", lw=1.4, color="C0", label=f"predicted (learned, {model} model)")
        if ref is not None:
            ax.plot(t_min, ref, "--", lw=1.0, color="C3", label=f"predicted ({reference}, {ref_model} model)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    axes[-1, 0].set_xlabel("time [min]")
    axes[0, 0].set_title(f"Actual vs. predicted, {pred.name} ({pred.split})")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
