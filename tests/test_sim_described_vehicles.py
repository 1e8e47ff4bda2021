"""The simulated vehicle flies a vehicle description and sends that vehicle's telemetry: a quad's
four ESCs and one pack (a motor fault shows as an ESC imbalance), and stock ArduPlane's
single-battery, ESC-index-2 layout, which the provisional derivation reads back."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.cli import main
from gcs_pdm.diagnosis.motor_imbalance import EscImbalanceDetector
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.estimation.estimator import StateEstimator
from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.sim.faults import FaultSpecError, parse_fault
from gcs_pdm.sim.model import VehicleModel, vehicle_config
from gcs_pdm.sim.record import fly
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.vehicle.presets import PRESETS
from gcs_pdm.logs.provisional_vehicle import observe_file
from gcs_pdm.mavlink.vehicle_mapping import frame_mapping


def test_quad_flies_its_mission_and_a_faulted_motor_shows_in_its_esc_telemetry(tmp_path):
    desc = PRESETS["quad-4s"]
    mission = tuple(mission_from_enu([(300, 0, 40), (300, 300, 40), (0, 300, 40)], takeoff_alt_m=40))
    cfg = vehicle_config(desc, mission=mission, faults=(parse_fault("motor:m2:0.3@leg:3-4", desc.motor_names),))
    rec = fly(cfg, tlog_path=tmp_path / "quad.tlog")
    assert rec.final.landed and not rec.final.failed
    assert [s for s, _ in rec.reached] == [1, 2, 3, 4, 5]
    assert rec.final.pack_soc.shape == (1,) and 0.8 < rec.final.pack_soc[0] < 0.97
    # what a ground station learns from it: a quad, one 4-cell pack, four ESCs
    # (a recorded flight carries no BATT_CAPACITY and drains too little to measure it: given)
    derived, _ = observe_file(tmp_path / "quad.tlog", capacities={0: 5000.0})
    assert derived.airframe.type == "multirotor"
    assert [(p.mavlink_battery_id, p.cells_series) for p in derived.packs] == [(0, 4)]
    assert [m.esc_index for m in derived.motors] == [0, 1, 2, 3]
    # the estimator and the ESC-imbalance detector on the description's frames
    est = StateEstimator(vehicle=desc)
    det = EscImbalanceDetector(desc.motor_names, est.motors.params)
    latest: dict[str, MotorFrame] = {}
    raised = []

    def consume(frame):
        est.consume(frame)
        if isinstance(frame, MotorFrame):
            latest[frame.motor] = frame
            if len(latest) == 4 and len({round(f.time_s, 1) for f in latest.values()}) == 1:
                bus = est.estimate().pack_voltage_v[0]
                currents = np.array([latest[n].current_a for n in desc.motor_names])
                raised.extend(f for ev, f in det.update(frame.time_s, currents, bus) if ev == "raise")

    replay_tlog(tmp_path / "quad.tlog", mapper=FrameMapper(frame_mapping(desc)), frame_consumer=consume)
    e = est.estimate()
    assert not e.mismatch and 0.8 < e.soc[0] < 1.0
    assert [f.component for f in raised] == ["m2"]
    assert raised[0].magnitude == pytest.approx(0.3, abs=0.08)
    assert raised[0].time_s > rec.fault_log[0]["time_s"]           # after the fault, not before
    # the diagnosis pipeline on the description does the same, and says how it diagnoses motors
    pipe = DiagnosisPipeline(vehicle=desc)
    replay_tlog(tmp_path / "quad.tlog", mapper=FrameMapper(frame_mapping(desc)), frame_consumer=pipe)
    motor_faults = [f for f in pipe.faults if f.type == "motor_power_loss"]
    assert [f.component for f in motor_faults] == ["m2"]
    assert motor_faults[0].magnitude == pytest.approx(0.3, abs=0.08)
    report = pipe.report()
    assert report["readiness"]["motor_diagnosis"].startswith("multirotor: the imbalance")
    assert set(report["estimate"]["motors"]) == {"m1", "m2", "m3", "m4"}


def test_single_battery_plane_sends_arduplanes_layout(tmp_path):
    desc = PRESETS["plane-3s"]
    mission = tuple(mission_from_enu([(800, 0, 60), (800, 800, 60)], takeoff_alt_m=60))
    rec = fly(vehicle_config(desc, mission=mission, ground_temp_c=25.0), tlog_path=tmp_path / "plane.tlog")
    assert rec.final.landed and not rec.final.failed
    derived, _ = observe_file(tmp_path / "plane.tlog", capacities={0: 3300.0})
    assert derived.airframe.type == "fixed_wing"
    assert [(p.mavlink_battery_id, p.cells_series, p.reports_temperature) for p in derived.packs] == [(0, 3, False)]
    assert [m.esc_index for m in derived.motors] == [2]
    # and the estimator on the preset keeps its one pack inside the model, temperature from the model
    est = StateEstimator(vehicle=desc)
    packs = []
    replay_tlog(tmp_path / "plane.tlog", mapper=FrameMapper(frame_mapping(desc)),
                frame_consumer=lambda f: (est.consume(f), isinstance(f, PackFrame) and packs.append(est.estimate())))
    assert packs and not est.estimate().mismatch
    assert est.estimate().modelled_temperature == ("battery",)
    assert packs[-1].soc[0] < packs[len(packs) // 4].soc[0]


def test_fault_specs_name_the_vehicles_motors_and_the_cli_takes_a_vehicle(tmp_path, capsys):
    with pytest.raises(FaultSpecError, match="one of m1, m2, m3, m4"):
        parse_fault("motor:aft:0.5@t:10", PRESETS["quad-4s"].motor_names)
    plan = tmp_path / "m.waypoints"
    from gcs_pdm.mavlink import mission_files

    mission_files.write_wpl(plan, mission_from_enu([(200, 0, 30)], takeoff_alt_m=30))
    out = tmp_path / "rec.tlog"
    assert main(["sim", "--vehicle", "quad-4s", "--mission", str(plan), "--record", str(out),
                 "--fault", "motor:m3:0.4@t:20"]) == 0
    assert "recorded" in capsys.readouterr().out
    derived, _ = observe_file(out, capacities={0: 5000.0})
    assert len(derived.motors) == 4
    # the CLI convention (docs/cli.md): one prefixed line on stderr, exit 2
    assert main(["sim", "--vehicle", "quad-4s", "--degrade", "LLF20:capacity=0.5", "--record", str(out)]) == 2
    assert "gcs-pdm sim: error: --params, --truth-seed and --degrade do not apply" in capsys.readouterr().err
