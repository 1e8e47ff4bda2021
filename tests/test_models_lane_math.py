"""The extended lanes' SIMD stages against libm and the plain OCV: ``lane_math``'s exp, log and asinh
(within one or two units in the last place; libm's value exactly where they hand a lane to libm),
and ``kernel.ocv_lanes`` (``_ocv_eval_at``'s value bit for bit from each lane's cached interval)."""
import math

import numpy as np
import pytest
from numba import njit

from gcs_pdm.models import kernel, lane_math
from gcs_pdm.models.params import extended_default

_JIT = dict(error_model="numpy")  # as the kernel's: lane_math's loops are written for it


@njit(**_JIT)
def _exp_log_asinh(x):
    """Rows: x, exp x, log x, asinh x, scratch."""
    a = np.empty((5, x.shape[0]))
    a[0] = x
    lane_math.exp_row(a, 0, 1, 0, x.shape[0])
    lane_math.log_row(a, 0, 2, 0, x.shape[0])
    lane_math.asinh_row(a, 0, 3, 4, 0, x.shape[0])
    return a


@njit(**_JIT)
def _libm(x):
    out = np.empty((3, x.shape[0]))
    for k in range(x.shape[0]):
        out[0, k] = math.exp(x[k])
        out[1, k] = math.log(x[k])
        out[2, k] = math.asinh(x[k])
    return out


def ulps(a, b):
    """Units in the last place between finite same-signed floats."""
    return np.abs(a.view(np.int64) - b.view(np.int64))


@pytest.fixture(scope="module")
def wide():
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.uniform(-708.0, 708.0, 40000), rng.uniform(-40.0, 2.0, 40000),
                        rng.uniform(-1.0, 1.0, 40000), rng.normal(0.0, 1e-9, 2000), rng.uniform(1.0, 60.0, 40000)])
    return x, _exp_log_asinh(x), _libm(x)


def test_exp_is_libms_within_one_ulp(wide):
    x, got, ref = wide
    d = ulps(got[1], ref[0])
    assert d.max() <= 1
    assert 0.0 < np.mean(d > 0) < 0.15  # not libm (measured: 7 %), so only the extended lanes use it


def test_log_is_libms_within_one_ulp(wide):
    x, got, ref = wide
    pos = x > 0
    assert ulps(got[2][pos], ref[1][pos]).max() <= 1


def test_asinh_is_libms_to_5e16_absolute_plus_two_ulps(wide):
    x, got, ref = wide
    assert np.all(np.abs(got[3] - ref[2]) <= 5e-16 + 4.5e-16 * np.abs(ref[2]))


def test_out_of_range_lanes_get_libms_value_exactly():
    x = np.array([0.0, -0.0, -1.0, np.nan, np.inf, -np.inf, 1e-310, 5e-324, 708.5, 709.7, 710.0, -708.5, -745.0,
                  -800.0, 1.7976931348623157e308, 2.2250738585072014e-308])
    got, ref = _exp_log_asinh(x), _libm(x)
    np.testing.assert_array_equal(got[1], ref[0])  # NaN in, NaN out
    np.testing.assert_array_equal(got[2], ref[1])


def test_interpreted_matches_compiled():
    """NUMBA_DISABLE_JIT runs the Python of these functions: the bit casts there are numpy's."""
    for x in (-3.7, 0.25, 12.5, -700.0):
        assert lane_math._exp_in_range.py_func(x) == lane_math._exp_in_range(x)
    for x in (0.3, 1.0, 7.25, 1e300):
        assert lane_math._log_in_range.py_func(x) == lane_math._log_in_range(x)


@njit(**_JIT)
def _ocv_path(y, d, soc_steps):
    """Each column of ``soc_steps`` is a lane's SoC at every step; the lanes' OCV, step by step, with
    the interval cache carried from step to step as the driver carries it."""
    n_steps, n_lanes = soc_steps.shape
    knot_row = np.zeros((1, n_lanes), dtype=np.int64)
    oc = np.empty((kernel.N_OCV_CACHE, n_lanes))
    oc[kernel.O_X] = np.inf
    a = np.empty((2, n_lanes))
    out = np.empty_like(soc_steps)
    for k in range(n_steps):
        a[0] = soc_steps[k]
        kernel.ocv_lanes(y, d, knot_row, 0, oc, 0, a, 0, 1, 0, n_lanes)
        out[k] = a[1]
    return out


@pytest.mark.parametrize("chemistry", ["lipo", "li-ion"])
def test_ocv_from_the_cached_interval_is_the_plain_ocv_bit_for_bit(chemistry):
    p = np.array(list(extended_default(chemistry).values()))
    y, d = np.empty((1, kernel.N_OCV_KNOTS)), np.empty((1, kernel.N_OCV_KNOTS))
    kernel._ocv_knots(p, y[0], d[0])
    knots = kernel.EXT_OCV_SOC
    rng = np.random.default_rng(2)
    lanes = [np.linspace(1.05, -0.05, 4001),                       # down through every knot and past both ends
             np.repeat(np.linspace(0.2, 0.9, 401), 10)[:4001],     # steps that stay in an interval
             rng.uniform(-0.1, 1.1, 4001),                         # jumps
             np.resize(np.concatenate([knots, np.nextafter(knots, 2.0), np.nextafter(knots, -2.0),
                                       [np.nan, 0.5, np.nan]]), 4001)]  # at and beside knots, NaN in between
    soc = np.ascontiguousarray(np.stack(lanes, axis=1))
    got = _ocv_path(y, d, soc)
    want = kernel.open_circuit_voltage(p, soc.ravel()).reshape(soc.shape)
    np.testing.assert_array_equal(got, want)
