"""The replay's compiled paths as ``gcs_pdm.compiled`` groups: small real workloads making the
same calls, with the same argument types, as a replay and the live loop's filters."""
from __future__ import annotations

from pathlib import Path

from gcs_pdm.compiled import Group

#: a recorded flight of the paper's aircraft with a motor fault (4 packs, 2 ESCs): what the live
#: loop's estimator, diagnoser and predictions see
WARM_UP_TLOG = Path(__file__).resolve().parents[2] / "fixtures" / "flights" / "fault_01.tlog"


def filters() -> None:
    """The diagnosis pipeline (state estimator, motor and pack-health diagnosers) over a recorded
    flight, as the live loop builds it (``service.adapters.make_diagnoser``) and a replay runs it."""
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog
    from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping
    from gcs_pdm.models.params import builtin
    from gcs_pdm.replay.vehicle import pipeline_for, replay_vehicle
    from gcs_pdm.vehicle.presets import resolve

    if not WARM_UP_TLOG.is_file():
        return
    diagnoser = pipeline_for(resolve("edge540"), builtin("paper_si"))
    replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(), frame_consumer=diagnoser.consume)
    # a replay without --vehicle: the description derived from the log (its own motor layout)
    desc, _ = replay_vehicle(WARM_UP_TLOG, None)
    if desc is not None:
        replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)),
                    frame_consumer=pipeline_for(desc).consume)


def held_current() -> None:
    """A replay's trace: the held-current Monte Carlo time to cut-off from an estimator."""
    import numpy as np

    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.estimation.prediction import predict_packs_at_current
    from gcs_pdm.models.params import builtin

    est = StateEstimator(builtin("paper_si"))  # the live loop's estimator of the paper's aircraft
    n_packs = est.packs.params.shape[0]
    predict_packs_at_current(est, np.full(n_packs, 15.0), current_a=np.full(n_packs, 10.0), horizon_s=120.0,
                             rng=np.random.default_rng(0), n_samples=4)


FILTERS = Group("filters", filters, ("gcs_pdm.estimation.ukf", "pack_step_one"))
HELD_CURRENT = Group("held_current", held_current,
                     ("gcs_pdm.estimation.prediction", "_held_current_to_cutoff_compiled"))
#: what ``gcs-pdm replay`` prepares
REPLAY_GROUPS = (FILTERS, HELD_CURRENT)
