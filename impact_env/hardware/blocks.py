"""Packed per-env rows: named blocks whose sizes come from the modules that own them.

Passing a few packed arrays instead of thirty-odd small ones is what makes a compiled call cheap
(each array argument costs tens of ns inside compiled code and about 0.3 us from Python).  Each
effect module says how big its parameter and state blocks are and how they are laid out inside
(``block_sizes``, ``pack_params`` and a ``*_packed`` kernel in :mod:`impact_env.effects`); this
module only strings the blocks together, in a fixed order, and hands the kernels an int64 table
of offsets: block ``j`` of row ``i`` is ``rows[i, offsets[j]:offsets[j + 1]]``.  No width or
offset is typed anywhere else.
"""

from __future__ import annotations

import numpy as np


class Blocks:
    """Blocks ``names`` (in order) of ``sizes`` floats: ``offsets`` (int64[len + 1]), ``size``."""

    def __init__(self, names: tuple[str, ...], sizes: tuple[int, ...]):
        if len(names) != len(sizes) or any(int(s) < 0 for s in sizes):
            raise ValueError(f"blocks {names} need one size >= 0 each, got {sizes}")
        self.names = tuple(names)
        self.offsets = np.concatenate([[0], np.cumsum(np.asarray(sizes, dtype=np.int64))]).astype(np.int64)
        self.size = int(self.offsets[-1])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def view(self, rows: np.ndarray, name: str) -> np.ndarray:
        """Block ``name`` of every row: a view of shape (n, block size)."""
        j = self.index(name)
        return rows[:, self.offsets[j]:self.offsets[j + 1]]
