"""The filters integrate a held current through a silent current sensor, but a prediction from it is a
guess: readiness says whose current is not being read instead of "ready"."""
from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.frames import AmbientFrame, MotorFrame, PackFrame
from gcs_pdm.vehicle.presets import PRESETS


def fly(current_until_s: float, seconds: float = 120.0):
    desc = PRESETS["quad-4s"]
    p = DiagnosisPipeline(vehicle=desc)
    for k in range(int(seconds * 10)):
        t = round(0.1 * (k + 1), 2)
        p.consume(PackFrame(t, "battery", 15.8 - 0.0001 * k, 10.0 if t < current_until_s else None, 30.0))
        for m in desc.motors:  # ESCs that report rpm and temperature but no current
            p.consume(MotorFrame(t, m.name, None, 6000.0, 40.0))
        if k % 10 == 0:
            p.consume(AmbientFrame(t, 20.0))
    return p.readiness()


def test_a_current_still_read_is_ready():
    assert fly(current_until_s=1e9)["prediction"] == "ready"


def test_a_held_current_is_said():
    r = fly(current_until_s=60.0)
    assert r["state"] == "ready"  # the state itself is still estimated
    assert r["prediction"].startswith("pack battery current not read for 60 s (held)")
