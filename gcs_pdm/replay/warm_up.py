"""The replay's compiled paths as ``gcs_pdm.compiled`` groups: small real workloads making the
same calls, with the same argument types, as a replay and the live loop's filters."""
from __future__ import annotations

import math
from pathlib import Path

from gcs_pdm.compiled import Group

#: a recorded flight of the paper's aircraft with a motor fault (4 packs, 2 ESCs): what the live
#: loop's estimator, diagnoser and predictions see
WARM_UP_TLOG = Path(__file__).resolve().parents[2] / "fixtures" / "flights" / "fault_01.tlog"

#: the ``filters`` group's pipelines fit no pack-health record: those fits are the ``pack_health``
#: group's, compiled at the same time in another child (a check is due once, with too short a record)
_NO_PACK_FITS = {"check_every_s": math.inf}


def filters() -> None:
    """The diagnosis pipeline (state estimator, motor diagnosers, prognosis) over a recorded flight,
    as the live loop builds it (``service.adapters.make_diagnoser``: ``pipeline_for`` the paper's
    aircraft) and a replay runs it; its pack-health fits are the ``pack_health`` group's."""
    from gcs_pdm.diagnosis.pack_health import PackHealthConfig
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog
    from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping
    from gcs_pdm.models.params import builtin
    from gcs_pdm.replay.vehicle import pipeline_for, replay_vehicle
    from gcs_pdm.vehicle.presets import resolve

    if not WARM_UP_TLOG.is_file():
        return
    no_fits = PackHealthConfig(**_NO_PACK_FITS)
    diagnoser = pipeline_for(resolve("edge540"), builtin("paper_si"), pack_config=no_fits)
    replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(), frame_consumer=diagnoser.consume)
    # a replay without --vehicle: the description derived from the log (its own motor layout)
    desc, _ = replay_vehicle(WARM_UP_TLOG, None)
    if desc is not None:
        replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)),
                    frame_consumer=pipeline_for(desc, pack_config=no_fits).consume)


def pack_health() -> None:
    """The pack-health monitor's fits (its cold Gauss-Newton search and a warm check's extension)
    on the recorded flight's pack frames, as the pipeline feeds them (``PackHealthMonitor.add``,
    ``check``), without the filters: the two groups compile in parallel."""
    from gcs_pdm.diagnosis.pack_health import PackHealthMonitor
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.frames import PackFrame
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog
    from gcs_pdm.models.params import PACK_NAMES, builtin

    if not WARM_UP_TLOG.is_file():
        return
    # the live loop's estimator of the paper's aircraft (``service.adapters.make_estimator``)
    monitor = PackHealthMonitor(StateEstimator(builtin("paper_si")).packs.params.copy())

    def consume(frame) -> None:
        if (isinstance(frame, PackFrame) and frame.pack in PACK_NAMES and frame.voltage_v is not None
                and frame.current_a is not None):
            t = float(frame.time_s)
            monitor.add(PACK_NAMES.index(frame.pack), t, float(frame.current_a), float(frame.voltage_v), 20.0)
            if monitor.due(t):
                monitor.check(t)

    replay_tlog(WARM_UP_TLOG, mapper=FrameMapper(), frame_consumer=consume)


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
PACK_HEALTH = Group("pack_health", pack_health, ("gcs_pdm.diagnosis.pack_health", "_run_and_linearise"))
HELD_CURRENT = Group("held_current", held_current,
                     ("gcs_pdm.estimation.prediction", "_held_current_to_cutoff_compiled"))
#: what ``gcs-pdm replay`` prepares, the longest to compile first (children start in this order)
REPLAY_GROUPS = (FILTERS, PACK_HEALTH, HELD_CURRENT)
