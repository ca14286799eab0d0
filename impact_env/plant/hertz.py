"""Closed-form Hertz impact results (Johnson, *Contact Mechanics*, 1985, sec 11.4), no gravity."""

from __future__ import annotations

from math import sqrt

CONTACT_TIME_FACTOR = 2.9432751843247047  # t_c = factor * d_max / v for F = c d^1.5


def max_penetration(m: float, c: float, v: float) -> float:
    """``d_max = (5 m v^2 / (4 c))^(2/5)`` (m), m the effective mass (kg), v the impact speed (m/s)."""
    return (5.0 * m * v * v / (4.0 * c)) ** 0.4


def contact_time(m: float, c: float, v: float) -> float:
    """Duration of an elastic Hertz impact (s)."""
    return CONTACT_TIME_FACTOR * max_penetration(m, c, v) / v


def peak_force(m: float, c: float, v: float) -> float:
    """``c d_max^1.5`` (N)."""
    d = max_penetration(m, c, v)
    return c * d * sqrt(d)


def max_contact_frequency(m: float, c: float, d: float) -> float:
    """Angular frequency of small oscillations about penetration d, ``sqrt(1.5 c d^0.5 / m)`` (rad/s)."""
    return sqrt(1.5 * c * sqrt(d) / m)
