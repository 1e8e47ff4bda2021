"""Record today's diagnosis outputs that the per-frame speed work (issue 18) must leave unchanged.

    PYTHONPATH=$PWD python tests/reference/make_diagnosis_reference.py

Writes ``diagnosis_pipeline.json`` next to this file, first recorded before the diagnoser's speed work
(which left it unchanged), re-recorded once after the model-mismatch advisory and the pack-current
guard fix (issue 15: new ``model_mismatch`` advisories, prognosis timing on flights they widen), and
after the pack-health warm start (issue 18: one event magnitude and one advisory residual moved) and
after the pack filter's temperature noise change (issue 31: two advisories' temperature evidence
moved), see tests/test_diagnosis_equivalence.py:
- ``synthetic``: the paper aircraft's pipeline on seeded synthetic flights (motor faults, a fault-free
  flight, an infeasible mission, degraded packs), with and without a mission: every fault and event,
  and the prognosis' latest p_failure;
- ``described``: the fixture tlogs (default frame mapping) and two synthetic flights through a
  pipeline on a vehicle description, the ``edge540`` preset (the ESC imbalance detector and
  ``_motor_set``: the path ``gcs-pdm replay`` takes with a description);
- ``imbalance``: the ESC imbalance detector alone on a hovering quad and hexacopter with a motor fault.

Compared by tests/test_diagnosis_equivalence.py within the tolerances stated there.
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
FLIGHTS = REPO / "fixtures" / "flights"

#: (name, seed, duration s, fault motor, magnitude, fault time, initial SoC, degraded packs, mission)
SYNTHETIC = (
    ("fwd_0.3", 21, 700.0, "fwd", 0.3, 350.0, 1.0, (), True),
    ("aft_0.6", 22, 700.0, "aft", 0.6, 350.0, 1.0, (), True),
    ("fault_free", 23, 1200.0, None, 0.0, None, 0.9, (), True),
    ("infeasible", 25, 1500.0, "fwd", 0.9, 300.0, 0.7, (), True),
    ("infeasible_no_mission", 25, 1500.0, "fwd", 0.9, 300.0, 0.7, (), False),
    ("degraded_packs", 24, 900.0, None, 0.0, None, 1.0, (("URA40", 0.65, 1.0), ("LLF20", 1.0, 2.5)), False),
)
DESCRIBED_FLIGHTS = ("fault_01", "fault_02", "fault_03", "learn_01")
#: (name, seed, duration s, fault motor, magnitude, fault time, initial SoC)
DESCRIBED_SYNTHETIC = (("synthetic_fwd_0.3", 21, 700.0, "fwd", 0.3, 350.0, 1.0),
                       ("synthetic_aft_0.6", 22, 700.0, "aft", 0.6, 350.0, 1.0))


def synthetic_flight(seed, duration, motor, magnitude, fault_time, soc, degraded):
    from gcs_pdm.estimation.synthetic import PackDegradation, fly_synthetic
    from gcs_pdm.sim.truth import true_parameters

    return fly_synthetic(true_parameters(), np.random.default_rng(seed), duration_s=duration, initial_soc=soc,
                         fault_motor=motor, fault_magnitude=magnitude, fault_time_s=fault_time,
                         degradation=tuple(PackDegradation(p, capacity=c, resistance=r) for p, c, r in degraded))


def pipeline_outputs(pipeline) -> dict:
    r = pipeline.report()
    latest = r["prognosis"]["latest"]
    return {"faults": r["faults"], "events": r["events"],
            "motor_power": r["motor_power"],
            "p_failure": None if latest is None else latest["p_failure"]}


def run_synthetic(name: str, seed, duration, motor, magnitude, fault_time, soc, degraded, mission) -> dict:
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
    from gcs_pdm.estimation.prediction import FutureLoad
    from gcs_pdm.models.params import default_set

    flight = synthetic_flight(seed, duration, motor, magnitude, fault_time, soc, degraded)
    p = DiagnosisPipeline(default_set())
    if mission:
        p.set_mission(FutureLoad(np.diff(flight.time_s, prepend=flight.time_s[0]), flight.shaft_power_w,
                                 float(np.mean(flight.ambient_c))), flight.time_s[0])
    for fr in flight.frames:
        p.consume(fr)
    return pipeline_outputs(p)


def described_pipeline():
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
    from gcs_pdm.vehicle.presets import PRESETS

    return DiagnosisPipeline(vehicle=PRESETS["edge540"])


def run_described(flight: str) -> dict:
    from gcs_pdm.mavlink.mapping import FrameMapper
    from gcs_pdm.mavlink.replay import replay_tlog

    p = described_pipeline()
    replay_tlog(FLIGHTS / f"{flight}.tlog", mapper=FrameMapper(), frame_consumer=p)
    return pipeline_outputs(p)


def run_described_synthetic(seed, duration, motor, magnitude, fault_time, soc) -> dict:
    p = described_pipeline()
    for fr in synthetic_flight(seed, duration, motor, magnitude, fault_time, soc, ()).frames:
        p.consume(fr)
    return pipeline_outputs(p)


def hover(preset: str, faulted: int, magnitude: float, n: int = 400, seed: int = 0):
    """A hovering multirotor's ESC currents (with noise) and bus voltage, a motor faulted."""
    from gcs_pdm.models import kernel, multirotor
    from gcs_pdm.models.topology import simulate_vehicle
    from gcs_pdm.vehicle.model_inputs import model_inputs
    from gcs_pdm.vehicle.presets import PRESETS

    desc = PRESETS[preset]
    inputs = model_inputs(desc)
    fault = np.zeros(len(desc.motors))
    fault[faulted] = magnitude
    a = desc.airframe
    # the fault switches on halfway: a raise, then a clear when it goes again at 3/4
    power = multirotor.hover_power(desc.mass_kg, len(desc.motors), a.rotor_diameter_m, a.figure_of_merit)
    x0 = kernel.initial_pack_state(inputs.pack_matrix, 0.9, 25.0)[None]
    run = simulate_vehicle(inputs, None, None, x0, np.full((1, inputs.n_motors), 25.0), np.ones(n), np.full(n, power),
                           20.0, fault[None], record=True)
    healthy = simulate_vehicle(inputs, None, None, x0, np.full((1, inputs.n_motors), 25.0), np.ones(n),
                               np.full(n, power), 20.0, np.zeros_like(fault)[None], record=True)
    rng = np.random.default_rng(seed)
    currents = np.where((np.arange(n) >= n // 4)[:, None] & (np.arange(n) < 3 * n // 4)[:, None],
                        run.motor_current[0], healthy.motor_current[0])
    currents = currents + rng.normal(0.0, 0.1, currents.shape)
    return inputs, currents, run.pack_voltage[0].mean(axis=1)


def run_imbalance(preset: str, faulted: int, magnitude: float) -> dict:
    from gcs_pdm.diagnosis.motor_imbalance import EscImbalanceDetector

    inputs, currents, bus = hover(preset, faulted, magnitude)
    det = EscImbalanceDetector(inputs.motor_names, inputs.motor_matrix)
    events = [(ev, f.to_dict()) for k in range(len(bus)) for ev, f in det.update(float(k), currents[k], bus[k])]
    return {"events": events, "faults": {n: f.to_dict() for n, f in det.faults.items()},
            "fault_vector": det.fault_vector().tolist(), "samples": det.samples,
            "low_power_skipped": det.low_power_skipped}


def main() -> int:
    logging.disable(logging.WARNING)
    out: dict = {"synthetic": {}, "described": {}, "imbalance": {}}
    for name, *case in SYNTHETIC:
        out["synthetic"][name] = run_synthetic(name, *case)
        print(name, len(out["synthetic"][name]["events"]), "events", file=sys.stderr)
    for flight in DESCRIBED_FLIGHTS:
        out["described"][flight] = run_described(flight)
        print(flight, len(out["described"][flight]["events"]), "events", file=sys.stderr)
    for name, *case in DESCRIBED_SYNTHETIC:
        out["described"][name] = run_described_synthetic(*case)
        print(name, len(out["described"][name]["events"]), "events", file=sys.stderr)
    for preset, faulted, magnitude in (("quad-4s", 1, 0.3), ("hex-6s", 4, 0.5), ("quad-4s", 2, 0.0)):
        out["imbalance"][f"{preset}_{faulted}_{magnitude}"] = run_imbalance(preset, faulted, magnitude)
    (HERE / "diagnosis_pipeline.json").write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
