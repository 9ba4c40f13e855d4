"""Scalar numba helpers of the fused spectral kernels: exact-form GELU with a vectorisable erf, its derivative.

GELU is 0.5 x (1 + erf(x / √2)), with erf as a rational function of x² on [−4, 4] (the form XLA and Eigen
vectorise; 6.5e-8 from math.erf in float64, ≈4e-7 evaluated in float32) instead of a library call, so
it vectorises; the derivative's exp(−x²/2) is a short polynomial raised to the 16th power
(tests/test_fast_decode.py checks both against math).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["FASTMATH_FLAGS", "erf", "gelu", "gelu_grad", "exp_neg"]

FASTMATH_FLAGS = {"nsz", "arcp", "contract", "reassoc"}  # numba fastmath flags (a set)


# Coefficients as float32 scalars (numba types them float32, so float32 pixels stay in float32 SIMD lanes;
# float64 pixels promote them exactly).
_P = tuple(np.float32(c) for c in (-2.72614225801306e-10, 2.77068142495902e-08, -2.10102402082508e-06,
                                   -5.69250639462346e-05, -7.34990630326855e-04, -2.95459980854025e-03,
                                   -1.60960333262415e-02))
_Q = tuple(np.float32(c) for c in (-1.45660718464996e-05, -2.13374055278905e-04, -1.68282697438203e-03,
                                   -7.37332916720468e-03, -1.42647390514189e-02))
_P0, _P1, _P2, _P3, _P4, _P5, _P6 = _P
_Q0, _Q1, _Q2, _Q3, _Q4 = _Q
_FOUR, _HALF, _ONE, _SQRT1_2, _INV_SQRT_2PI = (np.float32(v) for v in (4.0, 0.5, 1.0, 0.7071067811865476,
                                                                     0.3989422804014327))


@njit(cache=True, inline="always", fastmath=FASTMATH_FLAGS, error_model="numpy")
def erf(x):
    """erf(x) as P(x²)·x / Q(x²) on x clamped to [−4, 4] (module docstring)."""
    x = min(max(x, -_FOUR), _FOUR)
    x2 = x * x
    p = ((((((_P0 * x2 + _P1) * x2 + _P2) * x2 + _P3) * x2 + _P4) * x2 + _P5) * x2 + _P6)
    q = ((((_Q0 * x2 + _Q1) * x2 + _Q2) * x2 + _Q3) * x2 + _Q4)
    return x * p / q


@njit(cache=True, inline="always", fastmath=FASTMATH_FLAGS, error_model="numpy")
def gelu(x):
    return _HALF * x * (_ONE + erf(x * _SQRT1_2))


_E = tuple(np.float32(1.0 / math.factorial(k)) for k in range(10))
_E0, _E1, _E2, _E3, _E4, _E5, _E6, _E7, _E8, _E9 = _E
_EXP_MIN, _SIXTEENTH = np.float32(-24.0), np.float32(0.0625)


@njit(cache=True, inline="always", fastmath=FASTMATH_FLAGS, error_model="numpy")
def exp_neg(y):
    """exp(y) for y ≤ 0 as (Taylor₉(y/16))¹⁶, y clamped to [−24, 0]: a vectorisable exp for φ(x) =
    exp(−x²/2)/√(2π) in the GELU derivative (tests/test_fast_decode.py bounds the error of x·φ(x))."""
    u = max(y, _EXP_MIN) * _SIXTEENTH
    p = _E0 + u * (_E1 + u * (_E2 + u * (_E3 + u * (_E4 + u * (_E5 + u * (_E6 + u * (_E7 + u * (_E8 + u * _E9))))))))
    p = p * p
    p = p * p
    p = p * p
    return p * p


@njit(cache=True, inline="always", fastmath=FASTMATH_FLAGS, error_model="numpy")
def gelu_grad(x):
    """d gelu / dx = Φ(x) + x φ(x)."""
    return _HALF * (_ONE + erf(x * _SQRT1_2)) + x * _INV_SQRT_2PI * exp_neg(-_HALF * x * x)
