"""An append-only table of rows (float64 unless told) for data that arrives a little at a time.

Appending is amortised O(1) (the storage doubles when full); ``view()`` is the filled part, a
numpy view that stays valid (it keeps the storage it was taken from) even after later appends
and ``forget``. ``forget`` drops the oldest rows (a live session keeps a window, not hours);
``forgotten`` counts them, ``appended`` every row ever appended.
"""
from __future__ import annotations

import numpy as np


class Growing:
    def __init__(self, width: int, capacity: int = 1024, dtype=np.float64):
        self.width = width
        self._data = np.empty((capacity, width), dtype)
        self.n = 0
        self.forgotten = 0

    def __len__(self) -> int:
        return self.n

    def append(self, row) -> None:
        if self.n == len(self._data):
            self._grow(self.n + 1)
        self._data[self.n] = row
        self.n += 1

    def extend(self, rows) -> None:
        rows = np.asarray(rows, dtype=self._data.dtype).reshape(-1, self.width)
        if self.n + len(rows) > len(self._data):
            self._grow(self.n + len(rows))
        self._data[self.n:self.n + len(rows)] = rows
        self.n += len(rows)

    def reserve(self, rows: int) -> None:
        """Room for ``rows`` rows in all (a log's known length: no doubling past it)."""
        if rows > len(self._data):
            self._grow(rows, exact=True)

    def forget(self, rows: int) -> None:
        """Drop the first ``rows`` rows (into new storage: views taken before keep theirs)."""
        rows = min(max(rows, 0), self.n)
        if not rows:
            return
        kept = self.n - rows
        data = np.empty((max(2 * kept, 1024), self.width), self._data.dtype)
        data[:kept] = self._data[rows:self.n]
        self._data, self.n = data, kept
        self.forgotten += rows

    @property
    def appended(self) -> int:
        return self.forgotten + self.n

    def _grow(self, need: int, exact: bool = False) -> None:
        data = np.empty((need if exact else max(need, 2 * len(self._data)), self.width), self._data.dtype)
        data[:self.n] = self._data[:self.n]
        self._data = data

    def view(self) -> np.ndarray:
        """(n, width): every row so far."""
        return self._data[:self.n]

    def column(self, k: int) -> np.ndarray:
        return self._data[:self.n, k]

    @property
    def last(self) -> np.ndarray | None:
        return self._data[self.n - 1] if self.n else None
