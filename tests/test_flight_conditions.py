"""The live service and a replay predict from the same inputs: from the same frames, the telemetry
intake (``service.telemetry_intake``) and a replay's traced pipeline (``replay.vehicle``) work out
the same flight phase, air density, airspeed, climb, ambient temperature and load
(``estimation.flight_conditions``), and the intake's prediction is handed exactly those."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.estimation.flight_conditions import FlightConditions
from gcs_pdm.frames import AirdataFrame, AmbientFrame, PositionFrame, StatusFrame
from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping
from gcs_pdm.models.powertrain import air_density, shaft_power
from gcs_pdm.replay import vehicle as replay_vehicle
from gcs_pdm.replay.vehicle import TracedPipeline, flight_entry, pipeline_for
from gcs_pdm.service import adapters
from gcs_pdm.service.telemetry_intake import PREDICT_PERIOD_S, TelemetryIntake
from gcs_pdm.vehicle.presets import PRESETS

REPO = Path(__file__).resolve().parents[1]
FAULT_TLOG = REPO / "fixtures" / "flights" / "fault_03.tlog"  # the paper's aircraft, a motor fault (the shortest)


class _Link:
    """What the intake reads of its link while frames are handed to it directly."""
    received = 0
    target_system, target_component = 1, 1


class _FakePrediction:
    def __init__(self, n_packs: int):
        self.time_to_cutoff_s = np.full((n_packs, 3), math.nan)

    def to_dict(self) -> dict:
        return {}


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service

    svc = Service(load_config(env={}, data_dir=str(tmp_path_factory.mktemp("svc")), api_token="flight-conditions-test-token-7Qz",
                              vehicle="edge540"))
    yield svc
    svc.close()


def _mapper(desc):
    return FrameMapper(frame_mapping(desc), envelope=envelope(desc))


def test_the_live_intake_and_a_replay_predict_from_the_same_inputs(service, monkeypatch):
    desc = PRESETS["edge540"]
    monkeypatch.setattr(replay_vehicle, "DRAWING_CURRENT_A", math.inf)  # the trace's Monte Carlo is not compared
    # the replay, as `gcs-pdm replay --vehicle edge540` runs it: the driver passes frames over by type
    traced = TracedPipeline(desc, {"name": desc.name, "source": "given"}, period_s=PREDICT_PERIOD_S, background=False)
    replay_tlog(FAULT_TLOG, mapper=_mapper(desc), frame_consumer=traced)
    traced.close()
    replayed = [(e["time_s"], e["flight"]) for e in traced.trace]

    # the live intake on every frame of the same flight, with its own pipeline
    frames: list = []
    replay_tlog(FAULT_TLOG, mapper=_mapper(desc), frame_consumer=frames.append)
    diagnoser = pipeline_for(desc)
    intake = TelemetryIntake(service, _Link(), diagnoser.estimator, diagnoser, feed_estimator=False)
    handed: list[tuple[float, float, float]] = []

    def prediction_job(estimator, power, ambient_c, faults, limits=None, **_):
        now = intake.prediction_inputs(intake.time_s)
        handed.append((power, ambient_c, now.shaft_power_w, now.ambient_c))
        return lambda: _FakePrediction(len(estimator.pack_names))

    monkeypatch.setattr(adapters, "prediction_job", prediction_job)
    live = []
    due = -math.inf
    try:
        for frame in frames:
            intake.process(frame)
            if frame.time_s >= due:  # the replay's sampling instants (the first frame at or past each)
                due = frame.time_s + PREDICT_PERIOD_S
                if intake.estimator.ready():
                    live.append((round(frame.time_s, 3), flight_entry(intake.prediction_inputs(frame.time_s))))
    finally:
        intake.stop()
    assert len(replayed) > 20 and live == replayed
    flying = [f for _, f in replayed if f["flying"]]
    assert flying and all(f["shaft_power_w"] > 0 and f["air_density_kg_m3"] < 1.226 for f in flying)
    assert len({f["airspeed_mps"] for f in flying}) > 5  # the flight's own air data, not a default
    assert handed and all(p == core_p and a == core_a for p, a, core_p, core_a in handed)


def test_the_load_follows_the_airframe():
    conditions = FlightConditions()
    for frame in (StatusFrame(0.0, True, "AUTO", 4), PositionFrame(0.0, 47.0, 8.0, 600.0, 100.0, 0, 0, 0),
                  AirdataFrame(0.0, 20.0, 21.0, 1.5, 50.0, 90.0), AmbientFrame(0.0, 11.0)):
        conditions.consume(frame)

    class Ready:
        pack_current = np.array([30.0])

        def ready(self):
            return True

        def estimate(self):
            return type("E", (), {"pack_voltage_v": np.array([22.0])})()

    rho = float(air_density(600.0))
    paper = conditions.inputs(1.0, PRESETS["edge540"], Ready())
    assert paper.air_density_kg_m3 == rho and paper.ambient_c == 11.0 and paper.phase.flying
    assert paper.shaft_power_w == float(shaft_power(20.0, 1.5, rho))  # the paper's model, climb included
    quad = conditions.inputs(1.0, PRESETS["quad-4s"], Ready())
    assert quad.phase.flying and quad.shaft_power_w > 0  # forward flight at 20 m/s, level power
    plane = conditions.inputs(1.0, PRESETS["plane-3s"], Ready())
    assert plane.shaft_power_w is None  # a described fixed wing holds each pack's present draw
