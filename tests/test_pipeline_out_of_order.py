"""A battery frame older than the pack's last is skipped by the estimator (out of order); the
diagnoser must not take its voltage either: the ESC detector judges each motor's current against the
latest bus voltage."""
import math

from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.frames import PackFrame
from gcs_pdm.vehicle.presets import PRESETS


def test_an_out_of_order_battery_frame_leaves_the_bus_voltage_alone():
    p = DiagnosisPipeline(vehicle=PRESETS["quad-4s"])
    for k in range(20):
        p.consume(PackFrame(10.0 + k, "battery", 15.8, 12.0, 30.0))
    assert p._pack_v[0] == 15.8 and p._pack_v_time[0] == 29.0
    p.consume(PackFrame(5.0, "battery", 13.0, 12.0, 30.0))  # a delayed (or forged) old frame
    assert p.estimator.counters["out_of_order"] == 1
    assert p._pack_v[0] == 15.8 and p._pack_v_time[0] == 29.0
    p.consume(PackFrame(30.0, "battery", 15.7, 12.0, 30.0))
    assert p._pack_v[0] == 15.7 and math.isclose(p._pack_v_time[0], 30.0)
