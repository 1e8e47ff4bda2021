"""Whether the training flights determine each validation and test flight's prediction.

A fit keeps several candidates (one LM run per annealed start). Those whose training error is close
to the best one fit the training flights about equally well, so the training flights cannot tell them
apart. Where they also agree on a flight, the training flights determine its prediction. Where they
part, the flight depends on something the training flights do not show: a hotter pack, a deeper
discharge, a part of the open-circuit curve no flight started on. The chosen candidate's error on such
a flight then says little about the model: on the PyBaMM fixtures, validation picked the candidate
that missed the hot cut-off flight chen2020_03 by 260 mV, and its equally good siblings were 143 mV
away from it (docs/fitting.md, "Candidate agreement").

So a fit reports, per validation and test flight, how far its near-best candidates' voltage
predictions are from the chosen one's, and warns where that spread exceeds a multiple of the chosen
candidate's own training error. It cannot measure anything when only one candidate fits that well,
and says so.

Pure: traces in, a JSON-ready record out. ``procedure.fit_battery`` feeds it.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

#: a candidate counts as "about as good" when its training RMSE is within this factor of the best
#: one's (the extended variant's default choice, extended_train_tolerance, uses the same factor; the
#: paper variant's validation chooses among all its candidates)
AGREEMENT_TOLERANCE = 1.5
#: a flight is undetermined when the near-best candidates' predictions are further apart (RMS, V) than
#: this multiple of the chosen candidate's training RMSE: further apart than the fit's own error on
#: the flights it was trained on
AGREEMENT_FACTOR = 1.5


def near_best(train_rmse: Sequence[float], starts: Sequence[int], chosen: int,
              tolerance: float = AGREEMENT_TOLERANCE) -> list[int]:
    """Indices of the candidates within ``tolerance`` times the best training RMSE, the chosen one
    first. A candidate from the chosen one's own start (the run it was polished from) is not a second
    opinion and is left out."""
    rmse = np.asarray(train_rmse, dtype=np.float64)
    finite = np.isfinite(rmse)
    if not finite.any():
        return [chosen]
    limit = tolerance * float(np.min(rmse[finite]))
    others = [i for i in range(len(rmse))
              if i != chosen and finite[i] and rmse[i] <= limit and starts[i] != starts[chosen]]
    return [chosen] + others


def _rms_apart(a: np.ndarray, b: np.ndarray) -> float:
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d * d))) if d.size else float("nan")


def agreement_report(flights: Sequence[tuple[str, str]], voltages: Mapping[int, Sequence[np.ndarray]],
                     chosen: int, chosen_train_rmse: float, tolerance: float = AGREEMENT_TOLERANCE,
                     factor: float = AGREEMENT_FACTOR) -> tuple[dict, list[str]]:
    """(``candidate_agreement`` record of result.json, warnings).

    ``flights``: (name, split) of each validation and test flight; ``voltages[c][j]``: candidate c's
    predicted voltage on flight j (the chosen one and its near-best siblings, ``near_best``)."""
    others = [c for c in voltages if c != chosen]
    threshold = factor * chosen_train_rmse
    rule = (f"candidates within {tolerance:g}x the best training RMSE; a flight is undetermined when their "
            f"voltage predictions are more than {factor:g}x the chosen candidate's training RMSE apart (RMS)")
    record: dict = {"rule": rule, "candidates": [chosen] + others, "threshold_v": threshold,
                    "measured": bool(others), "flights": []}
    if not others:
        record["reason"] = (f"only the chosen candidate is within {tolerance:g}x the best training error: "
                            f"no second fit to compare with")
        record["flights"] = [{"flight": n, "split": s, "spread_v": None, "determined": None} for n, s in flights]
        return record, []
    warnings = []
    for j, (name, split) in enumerate(flights):
        apart = [_rms_apart(voltages[c][j], voltages[chosen][j]) for c in others]
        apart = [a for a in apart if np.isfinite(a)]
        spread = max(apart) if apart else None
        determined = None if spread is None else bool(spread <= threshold)
        record["flights"].append({"flight": name, "split": split, "spread_v": spread, "determined": determined})
        if determined is False:
            warnings.append(
                f"{split} flight {name}: not determined by the training flights: fits as good as the chosen one "
                f"on them predict its voltage {spread * 1000:.0f} mV apart (RMS), more than {factor:g}x the fit's "
                f"training error ({chosen_train_rmse * 1000:.0f} mV); its error says little about the model")
    return record, warnings
