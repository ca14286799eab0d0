"""impact_env._borrow: a borrowed array is the caller's memory (reads and writes go through), in
named tuples and tuples too, and the identity outside a kernel."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from impact_env._borrow import borrow
from impact_env._jit import jit


class Inner(NamedTuple):
    a: np.ndarray
    k: int


class Outer(NamedTuple):
    inner: Inner
    b: np.ndarray
    pair: tuple


@jit
def _write_through(o):
    o = borrow(o)
    row = o.inner.a[1]  # a view of a borrowed array
    row[0] += 1.0
    o.b[o.inner.k] = row.sum()
    o.pair[0][0] = 7.0
    return o.inner.a.shape[0] + o.b.shape[0]


def test_borrowed_arrays_are_the_callers_memory():
    a = np.arange(6.0).reshape(3, 2)
    b = np.zeros(4)
    c = np.zeros(1)
    n = _write_through(Outer(Inner(a, 2), b, (c, 3)))
    assert n == 7
    assert a[1, 0] == 3.0 and b[2] == 3.0 + 3.0 and c[0] == 7.0
    np.testing.assert_array_equal(a[[0, 2]], [[0.0, 1.0], [4.0, 5.0]])


def test_borrow_is_the_identity_in_python():
    a = np.zeros(3)
    assert borrow(a) is a
