"""Error figures of predicted versus measured traces (RMSE, mean absolute, max), in V, °C and °F."""
from __future__ import annotations

import numpy as np

C_TO_F_DIFF = 1.8  # a temperature *difference* of 1 °C is 1.8 °F


def error_stats(pred: np.ndarray, meas: np.ndarray) -> dict[str, float]:
    """RMSE, mean absolute and max absolute error over the samples where the measurement exists."""
    ok = np.isfinite(meas) & np.isfinite(pred)
    if not ok.any():
        return {"rmse": float("nan"), "mae": float("nan"), "max": float("nan"), "n": 0}
    e = pred[ok] - meas[ok]
    return {"rmse": float(np.sqrt(np.mean(e * e))), "mae": float(np.mean(np.abs(e))),
            "max": float(np.max(np.abs(e))), "n": int(ok.sum())}


def with_fahrenheit(stats: dict[str, float]) -> dict[str, float]:
    """°C error stats plus their °F equivalents (``rmse_f`` …)."""
    out = dict(stats)
    for k in ("rmse", "mae", "max"):
        out[f"{k}_f"] = stats[k] * C_TO_F_DIFF
    return out


def pooled(per_flight: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, float]:
    """Errors over all samples of several flights, plus the mean of the per-flight RMSE and MAE
    (the paper's "overall mean test error" is a mean over flights)."""
    if not per_flight:
        return {"rmse": float("nan"), "mae": float("nan"), "max": float("nan"), "n": 0,
                "mean_flight_rmse": float("nan"), "mean_flight_mae": float("nan")}
    pred = np.concatenate([p for p, _ in per_flight])
    meas = np.concatenate([m for _, m in per_flight])
    out = error_stats(pred, meas)
    flights = [f for f in (error_stats(p, m) for p, m in per_flight) if np.isfinite(f["rmse"])]
    # a quantity no flight measured (e.g. pack temperature in a log without it) has no mean: NaN -> null
    out["mean_flight_rmse"] = float(np.mean([f["rmse"] for f in flights])) if flights else float("nan")
    out["mean_flight_mae"] = float(np.mean([f["mae"] for f in flights])) if flights else float("nan")
    return out
