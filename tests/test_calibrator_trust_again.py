"""A self-calibrating filter that stopped trusting the voltage takes it again on the frame whose
innovation brings its window back under ``NIS_CLEAR``, and that frame's voltage updates it
(``PackCalibrator._update``: the compiled innovation and update are one call, applied only to a
filter trusted before the frame; this path updates it separately)."""
from __future__ import annotations

import copy
import math

from gcs_pdm.estimation.calibration import I_SOC, NIS_WINDOW, PackCalibrator, PackPrior
from gcs_pdm.models.chemistry import chemistry

CELLS, CURRENT_A = 4, 10.0


def test_the_frame_that_brings_the_trust_back_updates_the_filter():
    cal = PackCalibrator(PackPrior("lipo", CELLS, 5.0 * 3600.0))
    ocv = chemistry("lipo").ocv
    cal.initialise(0.0, CELLS * ocv(0.9), 0.0, 20.0)
    t = 0.0
    for k in range(NIS_WINDOW + 5):  # a voltage jumping ±1 V under load: no model follows it
        t += 1.0
        cal.step(t, 1.0, CURRENT_A, CELLS * ocv(0.9) + (1.0 if k % 2 else -1.0), 20.0)
    assert not cal.voltage_trusted and "cannot follow the voltage" in cal.why_not_voltage
    for _ in range(10 * NIS_WINDOW):  # then the model's own loaded voltage, until trusted again
        t += 1.0
        before = copy.deepcopy(cal)
        voltage = CELLS * ocv(cal.soc) - CURRENT_A * (cal.r0p + cal.r1p)
        cal.step(t, 1.0, CURRENT_A, voltage, 20.0)
        if cal.voltage_trusted:
            break
    assert cal.voltage_trusted and cal.why_not_voltage is None
    predicted_only = copy.deepcopy(before)
    predicted_only.step(t, 1.0, CURRENT_A, math.nan, 20.0)
    assert cal.counters["voltage_updates"] == before.counters["voltage_updates"] + 1
    # the voltage was taken: the SoC's variance shrank below the prediction's
    assert cal.P[I_SOC, I_SOC] < 0.99 * predicted_only.P[I_SOC, I_SOC]
