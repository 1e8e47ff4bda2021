"""Training flights the fitted circuit does not draw.

A fit's choice, its validation figures and its candidate agreement all compare fits with each other;
none says that the chosen one misses its own training flights. On cells whose electrolyte and
particles slow down in the cold (PyBaMM's OKane2022 and ORegan2022 sets), a cold high-rate climb
sags by volts within a minute and recovers as the pack self-heats, which the circuit cannot draw: the
fit misses that training flight by 600 mV and the rest by 100-300 mV, yet every other report looks
ordinary (docs/fitting.md, "Other parameter sets"). So a battery fit warns per training flight
whose voltage RMSE exceeds a per-cell limit.

Such a flight also spoils the fit of the others: least squares spends the circuit on the one flight
it cannot draw (okane2022_06 held 85 % of the training error, and the other flights were missed by
60-140 mV where they are 24-40 mV without it). So ``flights_to_leave_out`` picks the flights a fit
should be repeated without: over the per-cell limit and far above the typical training flight's
error, never more than half of them.

Pure: errors in, warnings out. ``procedure.fit_battery`` feeds it.
"""
from __future__ import annotations

import math
import statistics
from typing import Sequence

#: a training flight missed by more than this RMS per cell in series (V) is not drawn by the circuit:
#: 20 mV per cell is 100 mV on the paper's 5S pack, three times the paper's own fit error; the default
#: fit of the PyBaMM fixtures misses its training flights by 17-45 mV, and by 93 mV a 7-minute
#: cut-off climb in 6.5 C air (marquis2019_09)
MISFIT_PER_CELL_V = 0.020


def misfit_warnings(training_flights: Sequence[dict], cells: int,
                    per_cell_v: float = MISFIT_PER_CELL_V) -> list[str]:
    """One warning per training flight (an ``errors[...]["train"]["flights"]`` entry) whose voltage
    RMSE exceeds ``per_cell_v`` times ``cells``; a flight without voltage samples is not judged."""
    limit = per_cell_v * cells
    out = []
    for entry in training_flights:
        rmse = entry.get("voltage", {}).get("rmse")
        if rmse is None or not math.isfinite(rmse) or rmse <= limit:
            continue
        out.append(f"training flight {entry['flight']}: the fitted circuit misses it by {rmse * 1000:.0f} mV RMS "
                   f"({rmse / cells * 1000:.0f} mV per cell, over {per_cell_v * 1000:.0f}): the model does not draw "
                   f"what this pack did on it, and its predictions in such conditions are not supported")
    return out


def left_out_warning(flight: str, first_fit_rmse_v: float, final_rmse_v: float | None) -> str:
    """The warning for a training flight (segment) the fit was repeated without."""
    final = "?" if final_rmse_v is None else f"{final_rmse_v * 1000:.0f}"
    return (f"training flight {flight}: left out of the fit: the circuit missed it by {first_fit_rmse_v * 1000:.0f} mV "
            f"RMS with it in the training set, far beyond the other training flights, and the fit was repeated "
            f"without it (the final set misses it by {final} mV): the model does not draw what this pack did on it, "
            f"and its predictions in such conditions are not supported")


#: a flight is left out only when it is also this many times the median training flight's RMSE: on
#: cells the circuit draws badly everywhere, no flight stands out and none is left out
LEAVE_OUT_OVER_MEDIAN = 2.0
#: ... and the refit keeps at least this share of the training flights (segments)
KEEP_AT_LEAST = 0.5


def flights_to_leave_out(train_rmse: dict[str, float], cells: int, per_cell_v: float = MISFIT_PER_CELL_V,
                         over_median: float = LEAVE_OUT_OVER_MEDIAN,
                         keep_at_least: float = KEEP_AT_LEAST) -> list[str]:
    """Training flights (segments) to repeat the fit without, worst first: voltage RMSE over
    ``per_cell_v`` x ``cells`` and over ``over_median`` x the median flight's; at most as many as
    leave ``keep_at_least`` of them (and two) in the training set."""
    finite = {n: r for n, r in train_rmse.items() if r is not None and math.isfinite(r)}
    if len(finite) < 3:
        return []
    limit = max(per_cell_v * cells, over_median * statistics.median(finite.values()))
    worst = sorted((n for n, r in finite.items() if r > limit), key=lambda n: -finite[n])
    room = max(0, min(len(finite) - 2, int(math.floor(len(finite) * (1.0 - keep_at_least)))))
    return worst[:room]


def training_segments_to_leave_out(train_rmse: dict[str, float], log_of: dict[str, str], cells: int,
                                   per_cell_v: float = MISFIT_PER_CELL_V, over_median: float = LEAVE_OUT_OVER_MEDIAN,
                                   keep_at_least: float = KEEP_AT_LEAST) -> list[str]:
    """Every training segment to repeat the fit without: those ``flights_to_leave_out`` picks, and the
    other segments of their logs (``log_of``: segment -> log; a segment absent is its own log), since
    a log leaves whole. Empty when that would keep fewer than ``keep_at_least`` of the segments, or
    fewer than two."""
    picked = flights_to_leave_out(train_rmse, cells, per_cell_v, over_median, keep_at_least)
    logs = {log_of.get(n, n) for n in picked}
    out = picked + [n for n in train_rmse if n not in picked and log_of.get(n, n) in logs]
    kept = len(train_rmse) - len(out)
    if not picked or kept < 2 or kept < keep_at_least * len(train_rmse):
        return []
    return out
