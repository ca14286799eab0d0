"""Named positions in packed float arrays.

A kernel that takes a packed float64 vector (an effect's parameter block, a law's constants, a
row of records) reads its entries by name: the entries are the fields of one ``NamedTuple``
class, and :func:`positions` gives the instance of that class whose every field holds its own
position.  numba freezes such a module-level instance as a constant, so ``p[SAT.peak]`` compiles
to the same load as ``p[0]``; inserting a field changes no index anywhere::

    class SaturationParams(NamedTuple):
        peak: float  # N
        rms2: float  # N^2
    SAT = positions(SaturationParams)   # SaturationParams(peak=0, rms2=1)
    size = len(SAT)
"""

from __future__ import annotations

from typing import Any


def positions(cls: Any, start: int = 0) -> Any:
    """The instance of the NamedTuple class ``cls`` whose field ``k`` holds ``k``'s position
    (counted from ``start``: the entries follow others in the same array)."""
    return cls(*range(start, start + len(cls._fields)))
