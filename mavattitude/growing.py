"""An append-only table of rows (float64 unless told) for data that arrives a little at a time.

Appending is amortised O(1) (the storage doubles when full); ``view()`` is the filled part, a
numpy view that stays valid (it keeps the storage it was taken from, and rows are never
rewritten) even after later appends and ``forget``. ``forget`` drops the oldest rows (a live
session keeps a window, not hours) in O(1): a growth moves only the kept rows, into storage
twice their size, so a window's storage stays bounded. ``forgotten`` counts the dropped rows,
``appended`` every row ever appended.
"""
from __future__ import annotations

import numpy as np


class Growing:
    def __init__(self, width: int, capacity: int = 1024, dtype=np.float64):
        self.width = width
        self._data = np.empty((capacity, width), dtype)
        self._head = 0  # the first kept row's place in the storage (forgotten rows before it)
        self.n = 0
        self.forgotten = 0

    def __len__(self) -> int:
        return self.n

    def append(self, row) -> None:
        if self._head + self.n == len(self._data):
            self._grow(self.n + 1)
        self._data[self._head + self.n] = row
        self.n += 1

    def extend(self, rows) -> None:
        rows = np.asarray(rows, dtype=self._data.dtype).reshape(-1, self.width)
        if self._head + self.n + len(rows) > len(self._data):
            self._grow(self.n + len(rows))
        end = self._head + self.n
        self._data[end:end + len(rows)] = rows
        self.n += len(rows)

    def reserve(self, rows: int) -> None:
        """Room for ``rows`` rows in all (a log's known length: no doubling past it)."""
        if self._head + rows > len(self._data):
            self._grow(rows, exact=True)

    def forget(self, rows: int) -> None:
        """Drop the first ``rows`` rows: O(1), their storage is reclaimed at the next growth."""
        rows = min(max(rows, 0), self.n)
        self._head += rows
        self.n -= rows
        self.forgotten += rows

    @property
    def appended(self) -> int:
        return self.forgotten + self.n

    def _grow(self, need: int, exact: bool = False) -> None:
        """New storage (views taken before keep the old), the kept rows at its start."""
        size = need if exact else max(need, 2 * self.n, 1024)
        data = np.empty((size, self.width), self._data.dtype)
        data[:self.n] = self.view()
        self._data, self._head = data, 0

    def view(self) -> np.ndarray:
        """(n, width): every row kept."""
        return self._data[self._head:self._head + self.n]

    def column(self, k: int) -> np.ndarray:
        return self._data[self._head:self._head + self.n, k]

    @property
    def last(self) -> np.ndarray | None:
        return self._data[self._head + self.n - 1] if self.n else None
