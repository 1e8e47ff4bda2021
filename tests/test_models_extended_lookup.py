"""The extended circuit's fast paths against their plain definitions: the OCV's knot interval from
a grid table (``kernel._ocv_eval_at``) and the lanes' asinh by a log (``lane_math.asinh_row``)."""
import math

import numpy as np
import pytest
from numba import njit

from gcs_pdm.models import kernel, lane_math
from gcs_pdm.models.params import extended_default


def bisected_ocv(y, d, soc):
    """The OCV as ``_ocv_eval_at`` computed it before the table: the interval by bisection."""
    xs, last = kernel.EXT_OCV_SOC, kernel.N_OCV_KNOTS - 1
    if not soc > xs[0]:
        return y[0] + (soc - xs[0]) * d[0]
    if soc >= xs[last]:
        return y[last] + (soc - xs[last]) * d[last]
    k, hi = 0, last
    while hi - k > 1:
        mid = (k + hi) // 2
        if soc > xs[mid]:
            k = mid
        else:
            hi = mid
    hk = xs[k + 1] - xs[k]
    t = (soc - xs[k]) / hk
    t2 = t * t
    t3 = t2 * t
    return ((2.0 * t3 - 3.0 * t2 + 1.0) * y[k] + (t3 - 2.0 * t2 + t) * hk * d[k]
            + (-2.0 * t3 + 3.0 * t2) * y[k + 1] + (t3 - t2) * hk * d[k + 1])


@pytest.mark.parametrize("chemistry", ["lipo", "li-ion"])
def test_the_table_finds_the_bisections_interval_at_and_beside_every_knot(chemistry):
    p = np.array(list(extended_default(chemistry).values()))
    y, d = np.empty(kernel.N_OCV_KNOTS), np.empty(kernel.N_OCV_KNOTS)
    kernel._ocv_knots(p, y, d)
    knots = kernel.EXT_OCV_SOC
    soc = np.concatenate([np.linspace(-0.1, 1.1, 24001), knots, np.nextafter(knots, 2.0), np.nextafter(knots, -2.0),
                          [np.nan, 0.005 * 3, 0.995, 1e-300]])
    got = kernel.open_circuit_voltage(p, soc)
    np.testing.assert_array_equal(got, [bisected_ocv(y, d, s) for s in soc])  # NaN in, NaN out


@njit(error_model="numpy")
def _asinh_both(z, by_log, exact):
    a = np.empty((3, z.shape[0]))
    a[0] = z
    lane_math.asinh_row(a, 0, 1, 2, 0, z.shape[0])
    for k in range(z.shape[0]):
        by_log[k] = a[1, k]
        exact[k] = math.asinh(z[k])


def test_the_lanes_asinh_is_asinh_to_5e16_absolute_plus_two_ulps():
    z = np.concatenate([np.linspace(-60.0, 60.0, 200001), np.geomspace(1e-12, 1.0, 2001), [0.0, -0.0]])
    z = np.concatenate([z, -z])
    by_log, exact = np.empty_like(z), np.empty_like(z)
    _asinh_both(z, by_log, exact)
    # sign(z) log(|z| + sqrt(z² + 1)) with lane_math's log: a few 1e-16 near 0, one or two units in
    # the last place above
    assert np.all(np.abs(by_log - exact) <= 5e-16 + 4.5e-16 * np.abs(exact))
    np.testing.assert_array_equal(np.signbit(by_log), np.signbit(z))  # odd, -0 kept
