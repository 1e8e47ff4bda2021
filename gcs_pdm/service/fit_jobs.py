"""Fitting as a background job: flights from stored tlogs or uploaded files → the fitting
package's pure API → a new parameter set in the store (with provenance), plots on disk.

The job function only translates: which files, which packs, where the results go. The search
itself (SA → LM, train/validation/test) is ``gcs_pdm.fitting``'s.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

from gcs_pdm.service import adapters
from gcs_pdm.service.jobs import JobCancelled

log = logging.getLogger(__name__)


def make_fit_job(service) -> Callable:
    def fit_job(request: dict, progress: Callable[[float, str], None], should_stop: Callable[[], bool]) -> dict:
        fitting = adapters.fitting_api()
        flights = request["flights"]
        paths = {split: [service.resolve_flight_ref(ref) for ref in flights.get(split, [])]
                 for split in ("train", "validation", "test")}
        base = service.store.parameter_set(request["base_set"])
        out_dir = service.config.data_path / "jobs" / request.get("_job_id", "fit")
        progress(0.0, "loading flights")
        try:
            result = fitting.run_fit_job(
                component=request["component"], packs=list(request["packs"]), train=paths["train"],
                validation=paths["validation"], test=paths["test"], base=base, settings=request.get("settings", {}),
                out_dir=out_dir, progress=progress, should_stop=should_stop)
        except getattr(fitting, "FitCancelled", JobCancelled) as exc:
            raise JobCancelled(str(exc)) from None
        body = result.to_dict() if hasattr(result, "to_dict") else dict(result)
        ps = getattr(result, "parameter_set", None)
        if ps is not None and request.get("save_as"):
            ps = ps.replace(name=request["save_as"])
            service.store.save_parameter_set(ps, provenance={"source": "fit", "request": {
                k: v for k, v in request.items() if not k.startswith("_")}}, overwrite=True)
            body["saved_as"] = ps.name
        body.setdefault("plots", {p.stem: str(p) for p in sorted(Path(out_dir).glob("*.png"))})
        return body

    return fit_job
