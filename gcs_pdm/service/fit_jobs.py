"""Fitting as a background job: flights from stored tlogs or uploaded files → the fitting
package's pure API (``fit_battery`` per pack, ``fit_motor``) → a merged parameter set in the store
(with provenance), ``result.json`` and plots on disk.

The job only translates: which files, which packs, where the results go. The search itself
(SA → LM, train/validation/test) is ``gcs_pdm.fitting``'s.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Callable

from gcs_pdm.service import adapters
from gcs_pdm.service.jobs import JobCancelled

log = logging.getLogger(__name__)


def load_flights(path: Path, kind: str, pack: str | None):
    """The flights of one component in a file. Tlogs hold every pack; a CSV/Parquet table holds one
    component in the columns of ``gcs_pdm.fitting.tables.REQUIRED_COLUMNS``."""
    try:
        from gcs_pdm.fitting import logs
    except ImportError:
        logs = None
    if logs is not None and hasattr(logs, "read_flights"):
        return list(logs.read_flights(path, kind=kind, pack=pack))
    from gcs_pdm.fitting.tables import FlightDataError, flight_from_columns

    suffix = path.suffix.lower()
    if suffix == ".csv":
        import pandas as pd

        table = pd.read_csv(path)
    elif suffix in (".parquet", ".pq"):
        import pandas as pd

        table = pd.read_parquet(path)
    else:
        raise FlightDataError(f"{path.name}: reading {suffix} flights needs gcs_pdm.fitting.logs")
    return [flight_from_columns(path.stem, kind, {c: table[c].to_numpy() for c in table.columns},
                                source={"file": str(path), "pack": pack})]


def plot_predictions(result, out_dir: Path, prefix: str) -> dict[str, str]:
    """One PNG per flight: measured vs predicted (learned and reference) voltage and temperature."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out: dict[str, str] = {}
    for p in result.predictions:
        rows = 2 if p.measured_voltage is not None else 1
        fig, axes = plt.subplots(rows, 1, figsize=(8, 3 * rows), sharex=True, squeeze=False)
        ax = axes[0][0]
        if p.measured_voltage is not None:
            ax.plot(p.time_s, p.measured_voltage, ".", ms=2, label="measured")
            ax.plot(p.time_s, p.predicted_voltage, label="learned")
            ax.plot(p.time_s, p.reference_voltage, "--", label="reference")
            ax.set_ylabel("V")
            ax.legend(loc="best", fontsize=8)
            ax = axes[1][0]
        ax.plot(p.time_s, p.measured_temperature, ".", ms=2, label="measured")
        ax.plot(p.time_s, p.predicted_temperature, label="learned")
        ax.plot(p.time_s, p.reference_temperature, "--", label="reference")
        ax.set_ylabel("°C")
        ax.set_xlabel("s")
        axes[0][0].set_title(f"{prefix} {p.name} ({p.split})")
        name = f"{prefix}_{p.name}".replace("/", "_")
        path = out_dir / f"{name}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=80)
        plt.close(fig)
        out[name] = str(path)
    return out


def make_fit_job(service) -> Callable:
    def fit_job(request: dict, progress: Callable[[float, str], None], should_stop: Callable[[], bool]) -> dict:
        from gcs_pdm.fitting.procedure import FitSettings, fit_battery, fit_motor, merge_results
        from gcs_pdm.fitting.search import FitCancelled, SearchSettings
        from gcs_pdm.models.params import BUILTIN_SETS

        job_dir = service.config.data_path / "jobs" / request.get("_job_id", "fit")
        job_dir.mkdir(parents=True, exist_ok=True)
        component = request["component"]
        refs = request["flights"]
        base = service.store.parameter_set(request["base_set"])
        opts = dict(request.get("settings") or {})
        search = SearchSettings(**opts.pop("search", {}))
        ref_name = opts.pop("reference", "previous_si")
        settings = FitSettings(search=search, base=base.name if base.name in BUILTIN_SETS else "paper_si",
                               reference=ref_name, **opts)
        targets = list(request["packs"]) if component == "battery" else [None]
        results, body = {}, {"component": component, "fits": {}, "plots": {}}
        for k, pack in enumerate(targets):
            lo, hi = k / len(targets), (k + 1) / len(targets)
            label = pack or "motor"

            def part(fraction: float, stage: str = "", lo=lo, hi=hi, label=label) -> None:
                progress(lo + (hi - lo) * fraction, f"{label}: {stage}")

            part(0.0, "loading flights")
            splits = {s: [f for ref in refs.get(s, []) for f in load_flights(service.resolve_flight_ref(ref), component, pack)]
                      for s in ("train", "validation", "test")}
            try:
                if component == "battery":
                    res = fit_battery(splits["train"], splits["validation"], splits["test"], settings, pack=pack,
                                      progress=part, should_stop=should_stop)
                else:
                    res = fit_motor(splits["train"], splits["validation"], splits["test"], settings,
                                    progress=part, should_stop=should_stop)
            except FitCancelled as exc:
                raise JobCancelled(str(exc)) from None
            results[label] = res
            body["fits"][label] = res.to_dict()
            body["plots"].update(plot_predictions(res, job_dir, label))
        merged = merge_results(base, {p: r for p, r in results.items() if p != "motor"}, results.get("motor"),
                               name=request.get("save_as") or f"fit_{request.get('_job_id', 'job')}",
                               provenance={"source": "fit job", "job": request.get("_job_id")})
        body["parameter_set"] = merged.to_dict()
        if request.get("save_as"):
            service.store.save_parameter_set(merged, provenance={"source": "fit", "job": request.get("_job_id")},
                                             overwrite=True)
            body["saved_as"] = merged.name
        (job_dir / "result.json").write_text(json.dumps(body, default=str, indent=1))
        return body

    return fit_job
