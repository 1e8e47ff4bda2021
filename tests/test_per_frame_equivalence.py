"""The per-frame fast paths (issue 18) give exactly the numbers of the code they stand for:

- a telemetry frame's one-row filter steps with plain floats (``PackFilterBank.step_one`` →
  ``ukf.pack_step_one``, ``MotorThermalFilter.step_one`` → ``ukf.motor_step_one``) against the
  batched steps over one-element arrays, bit for bit, through gated spikes, re-locks, equal-time
  frames, missing channels and model-consistency flips;
- the pack-health fit's compiled linearisation (``pack_health._linearise``) against the numpy
  formulation it replaced;
- the pack-health record, appended to on every frame and read rarely, keeps the newest samples in order.
"""
from __future__ import annotations

import math
import random

import numpy as np

from gcs_pdm.diagnosis.pack_health import _linearise, _Record
from gcs_pdm.estimation.motor_filter import MotorThermalFilter
from gcs_pdm.estimation.pack_filter import PackFilterBank, PackFilterConfig
from gcs_pdm.models.params import default_set


def _pack_frames(rng, n):
    """(pack, dt, current, ambient, voltage, temperature): noisy readings with spikes, runs of
    spikes (re-locks), equal-time frames and missing channels."""
    frames = []
    for k in range(n):
        b = int(rng.integers(4))
        dt = 0.0 if rng.random() < 0.05 else float(rng.uniform(0.2, 1.5))
        v = 20.4 - 0.0005 * k + float(rng.normal(0.0, 0.04))
        if 300 <= k < 330 or rng.random() < 0.02:
            v += 1.5          # a run of spikes (re-lock) and lone ones (gated)
        if 600 <= k < 900:
            v -= 0.12         # a stretch the model misses: the consistency window raises
        if rng.random() < 0.05:
            v = math.nan
        temp = math.nan if rng.random() < 0.3 else 21.0 + float(rng.normal(0.0, 0.3))
        frames.append((b, dt, float(rng.uniform(0.0, 20.0)), 20.0, v, temp))
    return frames


def test_one_row_pack_step_is_the_batched_step_bit_for_bit():
    ps = default_set()
    config = PackFilterConfig(mismatch_window=40)
    one, rows = PackFilterBank(ps.pack_matrix(), config), PackFilterBank(ps.pack_matrix(), config)
    for bank in (one, rows):
        bank.initialise(np.arange(4), np.array([20.5, 20.3, 20.6, 20.1]), np.full(4, 8.0), np.full(4, 21.0))
    flips = 0
    for b, dt, cur, amb, v, temp in _pack_frames(np.random.default_rng(3), 1500):
        flips += one.step_one(b, dt, cur, amb, v, temp)
        rows.step(np.array([b]), np.array([dt]), np.array([cur]), amb, np.array([v]), np.array([temp]))
        for name in ("mean", "cov", "last_innovation", "rejected_total", "rejected_in_row", "relocks"):
            np.testing.assert_array_equal(getattr(one, name), getattr(rows, name), err_msg=name)
        for a, c in zip(one.consistency.arrays, rows.consistency.arrays):
            np.testing.assert_array_equal(a, c)
    # the flight exercised what the fast path must carry: gating, re-locks and consistency flips
    assert one.rejected_total.sum() > 0 and one.relocks.sum() > 0 and flips > 0


def test_one_row_motor_step_is_the_batched_step_bit_for_bit():
    motor = default_set().motor_vector()
    one, rows = MotorThermalFilter(motor, 2), MotorThermalFilter(motor, 2)
    for f in (one, rows):
        f.initialise(np.arange(2), np.array([25.0, 26.0]))
    rng = np.random.default_rng(5)
    for k in range(800):
        q = int(rng.integers(2))
        dt = 0.0 if rng.random() < 0.05 else float(rng.uniform(0.2, 1.5))
        temp = 30.0 + 0.01 * k + float(rng.normal(0.0, 0.3))
        if 200 <= k < 215 or rng.random() < 0.02:
            temp += 15.0
        if rng.random() < 0.2:
            temp = math.nan
        cur = float(rng.uniform(0.0, 25.0))
        one.step_one(q, dt, cur, 20.0, temp)
        rows.step(np.array([q]), np.array([dt]), np.array([cur]), 20.0, np.array([temp]))
        for name in ("mean", "cov", "rejected_total", "rejected_in_row", "relocks"):
            np.testing.assert_array_equal(getattr(one, name), getattr(rows, name), err_msg=name)
    assert one.rejected_total.sum() > 0 and one.relocks.sum() > 0


def _numpy_linearise(run_voltage, run_soc, voltage, keep, perturbed, eps, min_soc):
    """The numpy formulation ``_linearise`` replaced (one Gauss–Newton iteration of ``_gauss_newton``)."""
    free = np.zeros(3, dtype=bool)
    free[perturbed] = True
    r = voltage - run_voltage[0]
    columns = np.zeros((3, voltage.size))
    columns[perturbed] = (run_voltage[1:] - run_voltage[0]) / eps[perturbed][:, None]
    jac = columns.T
    use = keep & np.isfinite(r) & (run_soc >= min_soc)
    count = int(use.sum())
    if count < 20:
        return r, jac, use, keep, count, None, None
    res = r[use]
    centre = np.median(res)
    mad = 1.4826 * np.median(np.abs(res - centre)) + 1e-6
    keep = keep & ~(np.abs(r - centre) > 5.0 * mad)
    use = use & keep
    return r, jac, use, keep, count, jac[use][:, free], r[use]


def test_compiled_linearisation_is_the_numpy_one():
    rng = np.random.default_rng(11)
    eps = np.array([0.02, 0.005, 0.005])
    for n, perturbed in ((2400, np.array([0, 1, 2])), (1201, np.array([0, 2])), (40, np.array([0, 2])),
                         (25, np.array([0, 1, 2]))):
        base = 20.0 + np.cumsum(rng.normal(0.0, 0.01, n))
        run_voltage = np.stack([base] + [base + rng.normal(0.0, 1e-3, n) for _ in perturbed])
        run_voltage[0, rng.random(n) < 0.02] = np.nan              # a simulation that left the model
        voltage = base + rng.normal(0.0, 0.01, n)
        voltage[rng.random(n) < 0.03] += rng.choice([-1.0, 1.0]) * 0.5   # spikes for the MAD cut
        voltage = np.ascontiguousarray(np.stack([voltage, voltage]).T)[:, 0]  # a strided column, as the record's
        soc = np.linspace(1.0, 0.1, n)
        keep = rng.random(n) > 0.05
        got = _linearise(run_voltage, soc, voltage, keep, perturbed, eps, 0.2)
        want = _numpy_linearise(run_voltage, soc, voltage, keep, perturbed, eps, 0.2)
        assert got[4] == want[4]
        for g, w in zip(got[:4], want[:4]):
            np.testing.assert_array_equal(g, w)
        if want[5] is not None:
            np.testing.assert_array_equal(got[5], want[5])
            np.testing.assert_array_equal(got[6], want[6])
    # fewer than 20 usable samples: the fit stops there (the count says so)
    assert _linearise(run_voltage[:, :10], soc[:10], voltage[:10], keep[:10], perturbed, eps, 0.2)[4] < 20


def test_record_read_rarely_keeps_the_newest_samples_in_order():
    rnd = random.Random(1)
    for capacity in (1, 2, 5, 17):
        rec, model = _Record(capacity), []
        for k in range(4000):
            op = rnd.random()
            if op < 0.8:        # a frame's sample (several capacities' worth between some reads)
                row = (float(k), rnd.random(), rnd.random(), 15.0)
                rec.append(row)
                model = (model + [row])[-capacity:]
                assert rec.last_time == row[0]
            elif op < 0.99:     # a check reads it
                assert rec.array().tolist() == [list(r) for r in model]
                assert len(rec) == len(model) and list(rec) == model
                if model:
                    assert rec[0] == model[0] and rec[-1] == model[-1]
            else:               # a gap starts a new record
                rec.clear()
                model = []
                assert len(rec) == 0 and rec.last_time is None
