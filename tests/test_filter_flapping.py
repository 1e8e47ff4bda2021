"""A sensor flapping between two in-range readings (a loose thermistor or balance lead, two battery
monitors on one id): every switch is a burst of gated-out samples and then a re-lock, and a re-lock
multiplies the pack filter's covariance, the states the channel does not see included. Before the
estimator checked its filters after each re-lock, the compounded variances broke the covariance
(LinAlgError on every later frame of that pack, the replay ended with a traceback) or left NaN
states; now such a filter restarts from its next reading, counted and logged once."""
import logging

import numpy as np
import pytest

from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline
from gcs_pdm.frames import PackFrame
from gcs_pdm.vehicle.presets import PRESETS


def fly(temperatures, frames=3000, voltage=lambda k: 15.8 - 0.0002 * k, sample_every=50):
    """A quad-4s pack at 20 A, 10 frames a second, a slowly falling voltage; the estimator and its
    SoC (mean, sd) every ``sample_every`` frames."""
    pipeline = DiagnosisPipeline(vehicle=PRESETS["quad-4s"])
    socs = []
    for k in range(frames):
        pipeline.consume(PackFrame(0.1 * (k + 1), "battery", voltage(k), 20.0, temperatures(k)))
        if k % sample_every == sample_every - 1:
            e = pipeline.estimator.estimate(details=False)
            socs.append((e.soc[0], e.soc_sd[0]))
    return pipeline.estimator, np.array(socs)


def test_a_steady_sensor_never_restarts_the_filter():
    est, _ = fly(lambda k: 30.0)
    assert est.counters["filter_failures"] == 0


def test_a_flapping_temperature_restarts_the_filter_and_keeps_the_soc(caplog):
    _, steady = fly(lambda k: 30.0)
    with caplog.at_level(logging.WARNING, logger="gcs_pdm.estimation.estimator"):
        est, flapping = fly(lambda k: (30.0, 100.0)[(k // 5) % 2])
    assert est.counters["filter_failures"] > 0
    failures = [r for r in caplog.records if "its filter failed" in r.getMessage()]
    assert len(failures) == 1, "one warning per component; the counter tells the rest"
    # between restarts the SoC is the one the (steady) voltage implies, within the filter's own
    # uncertainty (half the temperatures read are 100 °C: the model's resistances follow them); just
    # after a restart it is unknown (NaN), never a number the filter cannot support
    known = np.isfinite(flapping[:, 0])
    assert known.mean() > 0.5
    assert (np.abs(flapping[known, 0] - steady[known, 0]) < 2.0 * flapping[known, 1]).all()
    assert (flapping[known, 1] <= 0.5).all()  # the ceiling: 10x the initial 0.05 in SoC sd


@pytest.mark.parametrize("low", [13.0, 17.5])
def test_a_flapping_voltage_never_raises(low):
    est, socs = fly(lambda k: 30.0, voltage=lambda k: (15.8, low)[(k // 5) % 2] - 0.0002 * k)
    assert np.isfinite(est.packs.cov).all()
    known = np.isfinite(socs[:, 0])
    assert known.any() and ((socs[known, 0] >= 0.0) & (socs[known, 0] <= 1.0)).all()
