"""Numbers written as ASCII into a byte buffer, in numba: the simtrace writer's formatting.

Each ``put_*`` writes one value at ``position`` of a uint8 ``buffer`` and returns the position after
it; ``put_fixed`` trims trailing zeros but keeps one decimal (30 -> "30.0"), ``put_general`` uses
``significant`` digits and switches to exponent form outside [1e-5, 10**significant), so small
DeepRacer rewards (1e-3, 1e-8) survive. NaN and infinities are written 'nan', 'inf', '-inf'.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# The kernels write ASCII codes: 10 newline, 32 space, 43 '+', 44 ',', 45 '-', 46 '.', 48 '0',
# 91 '[', 93 ']', 101 'e'.


@njit(cache=True)
def put_digits(buffer, position, value):
    """Decimal digits of a non-negative int64 value; returns the next position."""
    start = position
    while True:
        buffer[position] = 48 + value % 10
        value //= 10
        position += 1
        if value == 0:
            break
    low, high = start, position - 1
    while low < high:
        buffer[low], buffer[high] = buffer[high], buffer[low]
        low += 1
        high -= 1
    return position


@njit(cache=True)
def put_int(buffer, position, value):
    if value < 0:
        buffer[position] = 45
        position += 1
        value = -value
    return put_digits(buffer, position, value)


@njit(cache=True)
def put_rounded(buffer, position, value, decimals):
    """Finite `value` (|value| * 10**decimals < 9e18) rounded to `decimals`, trailing zeros
    trimmed with one kept: 30 -> '30.0'."""
    scale = np.int64(10) ** decimals
    quantity = np.int64(math.floor(abs(value) * 10.0 ** decimals + 0.5))
    if value < 0 and quantity != 0:
        buffer[position] = 45
        position += 1
    position = put_digits(buffer, position, quantity // scale)
    buffer[position] = 46
    fraction = quantity % scale
    for index in range(decimals, 0, -1):
        buffer[position + index] = 48 + fraction % 10
        fraction //= 10
    end = position + 1 + max(decimals, 1)
    if decimals == 0:
        buffer[end - 1] = 48
    while end > position + 2 and buffer[end - 1] == 48:
        end -= 1
    return end


@njit(cache=True)
def put_scientific(buffer, position, value, significant):
    """Finite non-zero `value` as mantissa 'e' signed two-digit exponent: 1.0e-08."""
    exponent = int(math.floor(math.log10(abs(value))))
    mantissa = value / 10.0 ** exponent
    if abs(mantissa) * 10.0 ** (significant - 1) + 0.5 >= 10.0 ** significant:
        mantissa /= 10.0
        exponent += 1
    position = put_rounded(buffer, position, mantissa, significant - 1)
    buffer[position] = 101
    buffer[position + 1] = 45 if exponent < 0 else 43
    position += 2
    if abs(exponent) < 10:
        buffer[position] = 48
        position += 1
    return put_digits(buffer, position, abs(exponent))


@njit(cache=True)
def put_special(buffer, position, value):
    """'nan', 'inf' or '-inf' (pandas and numpy parse these)."""
    word = "nan" if value != value else ("inf" if value > 0 else "-inf")
    for index in range(len(word)):
        buffer[position + index] = ord(word[index])
    return position + len(word)


@njit(cache=True)
def put_fixed(buffer, position, value, decimals):
    """`value` with at most `decimals` decimals (fewer when huge, exponent form beyond 9e18)."""
    if not math.isfinite(value):
        return put_special(buffer, position, value)
    while decimals > 0 and abs(value) * 10.0 ** decimals >= 9.0e18:
        decimals -= 1
    if abs(value) >= 9.0e18:
        return put_scientific(buffer, position, value, 15)
    return put_rounded(buffer, position, value, decimals)


@njit(cache=True)
def put_general(buffer, position, value, significant):
    """`significant` digits; exponent form outside [1e-5, 10**significant)."""
    if not math.isfinite(value):
        return put_special(buffer, position, value)
    if value == 0.0:
        return put_rounded(buffer, position, value, 1)
    exponent = int(math.floor(math.log10(abs(value))))
    if -5 <= exponent < significant:
        return put_rounded(buffer, position, value, significant - 1 - exponent)
    return put_scientific(buffer, position, value, significant)
