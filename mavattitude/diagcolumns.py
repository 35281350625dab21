"""An estimator's diagnostics kept for a whole replay in little memory, and given back exactly.

Most diagnostics change at a sensor's rate, not the IMU's: cpf-ekf's biases and earth field at
the compass's, its innovations NaN but at a GPS, baro or compass sample, VQF's rest flags
seldom. Kept row by row, an hour at 400 Hz of the seven estimators' is 240 MB; kept as runs of
one value where that is smaller (about half the series), 100 MB. A run is of one bit pattern
(NaN and -0.0 are values like any other), so ``Column.series`` gives back the very array that
was kept, to the bit, and ``Series`` gives one array at a time, as asked.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .growing import Growing

# Runs cost two numbers (the row it starts at, its value), a row one: a series with runs of
# fewer than 4 rows on average is kept row by row from then on.
MAX_RUN_SHARE = 0.25
MIN_ROWS = 4096  # rows seen before a series may be judged to change too often for runs


class Column:
    """One diagnostic over every IMU row of a replay, added a chunk at a time (``extend``).
    ``expected_rows``: the rows it will hold (room made at once if kept row by row)."""

    def __init__(self, dtype, expected_rows: int = 0):
        self.dtype = np.dtype(dtype)
        self.n = 0
        self.expected_rows = expected_rows
        self._bits = np.dtype(f"u{self.dtype.itemsize}")  # runs are of one bit pattern
        self._starts = Growing(1, dtype=np.int32)  # (rows: an int32 holds 170 years at 400 Hz)
        self._values = Growing(1, dtype=self.dtype)
        self._rows: Growing | None = None  # once kept row by row

    def extend(self, values) -> None:
        values = np.ascontiguousarray(values, dtype=self.dtype)
        if not len(values):
            return
        if self._rows is None:
            bits = values.view(self._bits)
            change = np.empty(len(values), bool)
            last = self._values.last
            change[0] = last is None or bits[0] != last.view(self._bits)[0]
            np.not_equal(bits[1:], bits[:-1], out=change[1:])
            at = np.flatnonzero(change)
            n = self.n + len(values)
            if n >= MIN_ROWS and self._values.n + len(at) > MAX_RUN_SHARE * n:
                rows = Growing(1, dtype=self.dtype)
                rows.reserve(max(self.expected_rows, n))
                rows.extend(self.series())
                self._rows = rows
                self._starts = self._values = None
            else:
                self._starts.extend(at + self.n)
                self._values.extend(values[at])
        if self._rows is not None:
            self._rows.extend(values)
        self.n += len(values)

    def series(self) -> np.ndarray:
        """(n,) every row, as added."""
        if self._rows is not None:
            return self._rows.column(0)
        starts = self._starts.column(0)
        return np.repeat(self._values.column(0), np.diff(starts, append=self.n))

    @property
    def nbytes(self) -> int:
        kept = [self._rows] if self._rows is not None else [self._starts, self._values]
        return sum(g.view().nbytes for g in kept)


class Series(Mapping):
    """An estimator's diagnostics, key -> (N,) array, each made from its ``Column`` when asked
    (and let go by the caller): a replay holds the columns, not every array at once."""

    def __init__(self, columns: dict[str, Column]):
        self._columns = columns

    def __getitem__(self, key: str) -> np.ndarray:
        return self._columns[key].series()

    def __iter__(self):
        return iter(self._columns)

    def __len__(self) -> int:
        return len(self._columns)

    def only(self, keys) -> Series:
        """These keys' columns, still made when asked."""
        return Series({k: self._columns[k] for k in keys})


def only(diagnostics: Mapping, keys) -> Mapping:
    """``diagnostics`` (a ``Series`` or a plain dict) with only ``keys``, as lazy as it was."""
    return diagnostics.only(keys) if isinstance(diagnostics, Series) else {k: diagnostics[k] for k in keys}
