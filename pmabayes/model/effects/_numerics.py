"""Compiled numerics the effects share: a smooth sign, a libm-free power and decay,
and Stribeck's exponential (all vectorise inside the simulator's batch loop).
"""

from __future__ import annotations

import numba
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["smooth_sign", "decay", "power"]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _expm1_over(q):
    # (e^q - 1) / q for |q| <= 0.625: its Taylor series to q^12, in Horner's form
    phq = 1.0 + q * (1 / 2 + q * (1 / 6 + q * (1 / 24 + q * (1 / 120 + q * (1 / 720 + q * (
        1 / 5040 + q * (1 / 40320 + q * (1 / 362880 + q * (1 / 3628800 + q * (
            1 / 39916800 + q * (1 / 479001600 + q / 6227020800)))))))))))
    return phq


@numba.njit(cache=True, error_model="numpy", inline="always")
def smooth_sign(u):
    """Hyperbolic tangent from polynomials only, so that loops calling it vectorise.

    libm's ``tanh`` is an opaque call that stops numba's loops from vectorising.

    Parameters
    ----------
    u : float
        Argument.

    Returns
    -------
    float
        ``tanh(u)`` to a relative error below 1e-13.
    """
    a = abs(u)
    a = a if a < 40.0 else 40.0  # builtin min() would block vectorisation
    q = -a / 64.0  # e^(-2a) = e^(128 q), |q| <= 0.625
    phq = _expm1_over(q)
    # e^(128 q) - 1 = q phq (e + 1)(e^2 + 1)...(e^64 + 1), free of cancellation
    e1 = 1.0 + q * phq
    e2 = e1 * e1
    e4 = e2 * e2
    e8 = e4 * e4
    e16 = e8 * e8
    e32 = e16 * e16
    e64 = e32 * e32
    prod = phq * (e1 + 1.0) * (e2 + 1.0) * (e4 + 1.0) * (e8 + 1.0) * (e16 + 1.0)
    prod *= (e32 + 1.0) * (e64 + 1.0)
    t = a * prod / 64.0 / (1.0 + e64 * e64)
    return t if u >= 0.0 else -t


@numba.njit(cache=True, error_model="numpy", inline="always")
def _exp_neg(a):
    # exp(-a) for a >= 0 from polynomials only, like smooth_sign, so that the loop that
    # calls it vectorises (relative error below 1e-11; exp(-80) ~ 2e-35 beyond a = 80)
    a = a if a < 80.0 else 80.0
    q = -a / 128.0
    phq = _expm1_over(q)
    e = 1.0 + q * phq
    for _ in range(7):
        e = e * e
    return e


@intrinsic
def _bits(typingctx, x):
    # the int64 with a float64's bits (LLVM bitcast; numba has no scalar one)
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, n):
    # the float64 with an int64's bits
    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@numba.njit(cache=True, error_model="numpy", inline="always")
def decay(y):
    """``exp(-y)`` and ``(1 - exp(-y)) / y`` for ``y >= 0``, from polynomials only.

    ``-y = n ln 2 + r``: ``n`` rounded by the ``1.5 * 2^52`` shift, ``r`` (``|r| <=
    0.347``) with ``ln 2`` in two parts, ``e^r`` a Taylor polynomial and ``2^n`` built
    from bits, as in :func:`power`.

    Parameters
    ----------
    y : float
        Argument, ``>= 0`` (a step over a time constant, say).

    Returns
    -------
    tuple of float
        ``(exp(-y), (1 - exp(-y)) / y)``, to a relative error below 2e-15 for
        ``y <= 40`` (the first is 0 beyond, an absolute error below 5e-18; the
        second is 1 at ``y = 0``, without cancellation for small ``y``).
    """
    a = y if y < 40.0 else 40.0  # builtin min() would block vectorisation
    # -a = n ln 2 + r, n = round(-a / ln 2) by the 1.5 * 2^52 shift, |r| <= 0.347
    s = a * -1.4426950408889634 + 6755399441055744.0
    n = s - 6755399441055744.0
    r = (n * -0.6931471803691238 - a) - n * 1.9082149292705877e-10  # ln 2 in two parts
    # e^r = 1 + r p, p = sum r^i / (i + 1)!, i <= 11
    r2 = r * r
    r4 = r2 * r2
    r8 = r4 * r4
    p = ((1.0 + r / 2) + r2 * (1 / 6 + r / 24)) + r4 * (
        (1 / 120 + r / 720) + r2 * (1 / 5040 + r / 40320))
    p = p + r8 * ((1 / 362880 + r / 3628800) + r2 * (1 / 39916800 + r / 479001600))
    ex = _from_bits((_bits(s) + 1023) << 52) * (1.0 + r * p)  # n in s's low bits
    # n = 0 (a < 0.347): r = -a exactly and (1 - e^-a) / a = p, without cancellation;
    # else 1 - e^-a >= 0.29
    far = (1.0 - ex) / (y if y > 0.34 else 0.34)
    return (ex if y <= 40.0 else 0.0), (p if n == 0.0 else far)


@numba.njit(cache=True, error_model="numpy", inline="always")
def power(y, e):
    """``y ** e`` for ``y > 0``, from bit operations and polynomials only (vectorises).

    ``e log2 y``: exponent and mantissa ``m`` from ``y``'s bits, ``m = 2^(j/4) (1 + f)``
    with ``j`` chosen by comparisons (selects) so that ``|f| <= 0.0905``, then a Taylor
    polynomial of ``log2(1 + f)``; ``2^v``: ``v = n + r`` with ``n`` rounded by the
    ``1.5 * 2^52`` shift, a Taylor polynomial of ``2^r`` and ``2^n`` built from bits.
    No division and no int/float conversion (AVX2 has no packed int64 -> double);
    the polynomials in Estrin's scheme, as the caller's batch loop is latency-bound.

    Parameters
    ----------
    y : float
        Base, in ``[2^-60, 2^60]`` (about ``[1e-18, 1e18]``; clamped to it).
    e : float
        Exponent, with ``|e ln y| <= 40`` (``e ln y`` is clamped to it).

    Returns
    -------
    float
        ``y ** e`` to a relative error below 3e-14 over that domain.
    """
    r = y if y > 8.673617379884035e-19 else 8.673617379884035e-19
    r = r if r < 1.152921504606847e18 else 1.152921504606847e18
    b = _bits(r)
    # exponent as a double: 2^52 + biased exponent in the bits of 2^52, minus both
    k = _from_bits((b >> 52) | 0x4330000000000000) - 4503599627371519.0
    m = _from_bits((b & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)  # in [1, 2)
    # m = 2^(j/4) m', |m' - 1| <= 0.0905: log2 m = j/4 + log2(1 + f), f = m' - 1
    c = 0.5 if m >= 1.8340080864093424 else 0.5946035575013605
    c = c if m >= 1.5422108254079407 else 0.7071067811865476
    c = c if m >= 1.2968395546510096 else 0.8408964152537145
    c = c if m >= 1.0905077326652577 else 1.0
    j = 1.0 if m >= 1.8340080864093424 else 0.75
    j = j if m >= 1.5422108254079407 else 0.5
    j = j if m >= 1.2968395546510096 else 0.25
    j = j if m >= 1.0905077326652577 else 0.0
    f = m * c - 1.0
    # log2(1 + f) = (f - f^2/2 + ... - f^14/14) / ln 2
    f2 = f * f
    f4 = f2 * f2
    f8 = f4 * f4
    a = (1.4426950408889634 - 0.7213475204444817 * f) + f2 * (
        0.48089834696298783 - 0.36067376022224085 * f)
    a = a + f4 * ((0.28853900817779266 - 0.24044917348149392 * f) + f2 * (
        0.20609929155556622 - 0.18033688011112042 * f))
    d = (0.1602994489876626 - 0.14426950408889633 * f) + f2 * (
        0.1311540946262694 - 0.12022458674074696 * f)
    d = d + f4 * (0.11097654160684335 - 0.10304964577778311 * f)
    v = e * ((k + j) + f * (a + f8 * d))  # e log2 y
    v = v if v < 57.70780163555854 else 57.70780163555854  # |e ln y| <= 40
    v = v if v > -57.70780163555854 else -57.70780163555854
    s = v + 6755399441055744.0  # n + 1.5 * 2^52, n = round(v)
    r = v - (s - 6755399441055744.0)  # exact, |r| <= 1/2
    # 2^r = sum (r ln 2)^i / i!, i <= 13
    r2 = r * r
    r4 = r2 * r2
    r8 = r4 * r4
    a = (1.0 + 0.6931471805599453 * r) + r2 * (0.2402265069591007 + 0.055504108664821576 * r)
    d = (0.009618129107628477 + 0.0013333558146428441 * r) + r2 * (
        0.00015403530393381606 + 1.5252733804059838e-05 * r)
    g = (1.3215486790144305e-06 + 1.0178086009239696e-07 * r) + r2 * (
        7.054911620801121e-09 + 4.44553827187081e-10 * r)
    p = (a + r4 * d) + r8 * (g + r4 * (2.5678435993488196e-11 + 1.3691488853904124e-12 * r))
    return p * _from_bits((_bits(s) + 1023) << 52)  # n in s's low bits: 2^n
