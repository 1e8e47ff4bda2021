"""exp and log from IEEE-754 +, -, *, / and frexp/ldexp only, so every machine gets the same bits.

numpy's ``np.exp``/``np.log``/``np.sin`` are libm's on some CPUs and numpy's own SIMD code on others
(AVX-512), and libm itself picks FMA or plain variants by CPU: each is within an ulp or so, but not the
same ulp. The fit's Levenberg-Marquardt amplifies such a last bit into another answer (a different
test-flight error, docs/notes/2026-11-27-fit-determinism.md), so the maps it runs through — unit cube
to physical values (:class:`~gcs_pdm.fitting.problem.ParameterSpace`) and back — use these instead.
Basic arithmetic is correctly rounded by IEEE-754 and numpy's elementwise operators never fuse a
multiply and an add, so the result below is the same everywhere; accuracy is within ~2 ulp.
"""
from __future__ import annotations

import numpy as np

# ln 2 split so that k * LN2_HI is exact for |k| < 2^11 (Cody-Waite range reduction)
LN2_HI = 6.93147180369123816490e-01
LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e+00
_EXP_TERMS = 14      # Taylor terms on |r| <= ln2 / 2: remainder < 1e-17 relative
_LOG_TERMS = 12      # odd powers of s = (m - 1) / (m + 1), |s| <= 0.172: remainder < 1e-19


def exp(x) -> np.ndarray:
    """e**x, float64, the same bits on every IEEE-754 machine; overflows to inf above ~709.78."""
    x = np.asarray(x, dtype=np.float64)
    xc = np.clip(np.where(np.isnan(x), 0.0, x), -745.2, 709.79)
    k = np.rint(xc * _INV_LN2)
    r = (xc - k * LN2_HI) - k * LN2_LO
    p = np.ones_like(r)
    for n in range(_EXP_TERMS, 0, -1):  # Horner on 1 + r (1 + r/2 (1 + r/3 (...)))
        p = 1.0 + p * r / n
    with np.errstate(over="ignore"):
        out = np.ldexp(p, k.astype(np.int64))
    out = np.where(x > 709.79, np.inf, out)
    return np.where(np.isnan(x), np.nan, out)


def log(x) -> np.ndarray:
    """Natural log, float64, the same bits on every IEEE-754 machine; -inf at 0, NaN below."""
    x = np.asarray(x, dtype=np.float64)
    m, e = np.frexp(np.where((x > 0) & np.isfinite(x), x, 1.0))
    low = m < 0.7071067811865476
    m = np.where(low, 2.0 * m, m)
    e = np.where(low, e - 1, e).astype(np.float64)
    s = (m - 1.0) / (m + 1.0)
    s2 = s * s
    q = np.zeros_like(s)
    for n in range(2 * _LOG_TERMS - 1, 0, -2):
        q = 1.0 / n + s2 * q
    out = e * LN2_HI + (e * LN2_LO + 2.0 * s * q)
    out = np.where(x == 0, -np.inf, out)
    out = np.where((x < 0) | np.isnan(x), np.nan, out)
    return np.where(np.isposinf(x), np.inf, out)
