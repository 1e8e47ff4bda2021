"""``exp`` and ``log`` over a row of lanes in plain arithmetic, so a lane loop compiles to SIMD.

A call to libm's ``exp``/``log`` cannot be vectorised: in the lanes driver (``gcs_pdm.models.lanes``)
the extended packs' three exponentials and one log per step were ≈ 5.5 ns each, a third of the
Monte Carlo's time (docs/notes/2026-11-27-extended-mc-2.md). These are fdlibm's algorithms (the
reduction to [-ln2/2, ln2/2] with its rational approximation for ``exp``; the reduction to
[√2/2, √2) with its series in s = f/(2+f) for ``log``), written without branches and without
float↔int conversions (AVX2 has no vector int64 conversion: the exponent is moved with the
1.5·2^52 shift and bit casts), so the loops over lanes compile to four lanes an instruction.

Error: under one unit in the last place (fdlibm's bound); against glibc's, which rounds correctly
in almost every case, about one result in ten differs in its last bit
(tests/test_models_lane_math.py measures it). So they are for the extended packs' lanes only: the
paper packs keep libm's numbers bit for bit. Inputs outside the range the arithmetic covers (|x| >
708 for ``exp``; zero, negative, subnormal, infinite or NaN for ``log``) are counted in the vector
loop and computed by libm afterwards: those lanes give libm's value exactly.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: the kernel's options (``kernel._JIT``; not imported: the kernel imports this module). Inlined into
#: a caller, these functions take the caller's error model: it must be numpy's, since a division
#: check (Python's) is a branch that keeps a loop from vectorising
_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(inline="always", **_JIT)
def _bits_of(x):
    """The IEEE-754 bits of a float64 as an int64 (a bit cast: free, and it vectorises)."""
    return np.float64(x).view(np.int64)


@njit(inline="always", **_JIT)
def _float_of(i):
    """The float64 whose IEEE-754 bits are the int64 ``i``."""
    return np.int64(i).view(np.float64)


#: x + SHIFT rounds x to an integer n (|n| < 2^51) and leaves n in the low bits of the sum's bits
_SHIFT = 6755399441055744.0  # 1.5 * 2^52
_SHIFT_BITS = 0x4338000000000000
_EXP_BIAS_BITS = 1023
_INV_LN2 = 1.44269504088896338700e+00
# ln 2 split so that n * _LN2_HI is exact for |n| < 2^11
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
# fdlibm's exp: the rational approximation's polynomial on [-ln2/2, ln2/2]
_P1 = 1.66666666666666019037e-01
_P2 = -2.77777777770155933842e-03
_P3 = 6.61375632143793436117e-05
_P4 = -1.65339022054652515390e-06
_P5 = 4.13813679705723846039e-08
#: |x| up to which the arithmetic's result is a normal number (beyond: libm)
_EXP_LIMIT = 708.0
# fdlibm's log: log(1+f) = f - f²/2 + s (f²/2 + R(s²)), s = f / (2 + f)
_LG1 = 6.666666666666735130e-01
_LG2 = 3.999999999940941908e-01
_LG3 = 2.857142874366239149e-01
_LG4 = 2.222219843214978396e-01
_LG5 = 1.818357216161805012e-01
_LG6 = 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01
_MANTISSA_BITS = 0x000FFFFFFFFFFFFF
_SMALLEST_NORMAL = 2.2250738585072014e-308


@njit(inline="always", **_JIT)
def _exp_in_range(x):
    """e^x for |x| <= ``_EXP_LIMIT`` (outside it, garbage: the caller gives those lanes to libm)."""
    x = min(max(x, -_EXP_LIMIT), _EXP_LIMIT)  # keeps the out-of-range lanes' arithmetic harmless
    shifted = x * _INV_LN2 + _SHIFT
    n = shifted - _SHIFT  # round(x / ln 2)
    hi = x - n * _LN2_HI
    lo = n * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    return y * _float_of((_bits_of(shifted) - _SHIFT_BITS + _EXP_BIAS_BITS) << 52)  # y * 2^n


@njit(inline="always", **_JIT)
def _log_in_range(x):
    """log x for a positive normal finite x (otherwise garbage: the caller gives those lanes to libm)."""
    bits = _bits_of(x)
    mantissa = bits & _MANTISSA_BITS
    # 1 when the mantissa is >= ~√2 (fdlibm's test on the high word): then x = 2^(k+1) (m/2)
    up = (((mantissa >> 32) + 0x95F64) & 0x100000) >> 20
    m = _float_of(mantissa | ((_EXP_BIAS_BITS - up) << 52))  # in [√2/2, √2)
    k = (bits >> 52) - _EXP_BIAS_BITS + up
    dk = _float_of(_SHIFT_BITS + k) - _SHIFT  # float(k) without a conversion instruction
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    r = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7))) + w * (_LG2 + w * (_LG4 + w * _LG6))
    hfsq = 0.5 * f * f
    return dk * _LN2_HI - ((hfsq - (s * (hfsq + r) + dk * _LN2_LO)) - f)


@njit(inline="always", **_JIT)
def _exp_covers(x):
    return abs(x) <= _EXP_LIMIT


@njit(inline="always", **_JIT)
def _log_covers(x):
    return _SMALLEST_NORMAL <= x <= 1.7976931348623157e308


@njit(inline="always", **_JIT)
def _libm_exp(x):
    return math.exp(x)


@njit(inline="always", **_JIT)
def _libm_log(x):
    return math.log(x)


@njit(inline="always", **_JIT)
def _map_row(a, src, dst, lo, hi, arithmetic, covers, libm):
    """``a[dst, l] = arithmetic(a[src, l])`` over the lanes in one SIMD loop, then libm's value for
    the lanes the arithmetic does not cover (numba passes the functions as constants: direct calls)."""
    n_outside = 0
    for l in range(lo, hi):
        x = a[src, l]
        a[dst, l] = arithmetic(x)
        n_outside += not covers(x)
    if n_outside:
        for l in range(lo, hi):
            if not covers(a[src, l]):
                a[dst, l] = libm(a[src, l])


@njit(inline="always", **_JIT)
def exp_row(a, src, dst, lo, hi):
    """``a[dst, l] = exp(a[src, l])`` for lanes ``lo`` … ``hi`` - 1 (``src`` != ``dst``)."""
    _map_row(a, src, dst, lo, hi, _exp_in_range, _exp_covers, _libm_exp)


@njit(inline="always", **_JIT)
def log_row(a, src, dst, lo, hi):
    """``a[dst, l] = log(a[src, l])`` for lanes ``lo`` … ``hi`` - 1 (``src`` != ``dst``)."""
    _map_row(a, src, dst, lo, hi, _log_in_range, _log_covers, _libm_log)


@njit(inline="always", **_JIT)
def asinh_row(a, src, dst, scratch, lo, hi):
    """``a[dst, l] = asinh(a[src, l])`` as sign(z) log(|z| + √(z² + 1)) with ``log_row`` (libm's asinh
    goes through log1p: three exponentials' worth); rows ``src``, ``dst`` and ``scratch`` distinct. Near z = 0 this is not asinh's correctly rounded value (a few 1e-16 absolute off),
    elsewhere within two units in the last place (tests/test_models_lane_math.py)."""
    for l in range(lo, hi):
        z = a[src, l]
        a[scratch, l] = abs(z) + math.sqrt(z * z + 1.0)
    log_row(a, scratch, dst, lo, hi)
    for l in range(lo, hi):
        a[dst, l] = math.copysign(a[dst, l], a[src, l])
