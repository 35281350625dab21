"""A whole log's IMU rows as the runner reads them, without a copy of the log.

The runner keeps what it is given as rows (time, gyro, accelerometer, arrival: float64, one
row a sample), which a live link's packets fill a few at a time (``growing.Growing``). A log's
IMU is given at once, and its flight already holds it: ``ImuRows`` reads the flight's own
arrays and stacks only the rows asked for (a step's, or a run's at its start), so an hour at
400 Hz is not held twice (92 MB). What it gives is what the rows would hold, to the bit:
the same values, in float64, in arrays of the same layout.
"""
from __future__ import annotations

import numpy as np


class ImuRows:
    """``Growing``'s part that the runner uses, over ``t`` (N,), ``gyro`` (N, 3), ``accel``
    (N, 3) and ``arrival`` (N,). ``view()`` reads like the (N, 8) array of rows: a slice of rows
    is stacked (a new array), a column is the array itself (``[:, 0]``, ``[a:b, -1]``)."""

    width = 8

    def __init__(self, t, gyro, accel, arrival):
        self._t = np.asarray(t, dtype=np.float64)
        self._gyro = np.asarray(gyro, dtype=np.float64)
        self._accel = np.asarray(accel, dtype=np.float64)
        self._arrival = np.asarray(arrival, dtype=np.float64)  # as a row holds it (a .bin's offsets are int64)
        self.forgotten = 0

    @property
    def n(self) -> int:
        return len(self._t)

    def __len__(self) -> int:
        return self.n

    def view(self) -> ImuRows:
        return self

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n, self.width)

    def __getitem__(self, index):
        rows, col = index if isinstance(index, tuple) else (index, None)
        if col is None:  # whole rows: (m, 8), or (8,) for one
            if isinstance(rows, slice):
                return np.column_stack([self._t[rows], self._gyro[rows], self._accel[rows], self._arrival[rows]])
            return np.concatenate([[self._t[rows]], self._gyro[rows], self._accel[rows], [self._arrival[rows]]])
        if col in (0, -self.width):
            return self._t[rows]
        if col in (self.width - 1, -1):
            return self._arrival[rows]
        return self[rows][..., col]  # (not read by the runner: a gyro or accelerometer column)

    def column(self, k: int) -> np.ndarray:
        return self[:, k]

    @property
    def last(self) -> np.ndarray | None:
        return self[self.n - 1] if self.n else None

    def extend(self, rows) -> None:
        """More rows after the log's (not needed by a replay: the runner takes any source)."""
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, self.width)
        self._t = np.concatenate([self._t, rows[:, 0]])
        self._gyro = np.concatenate([self._gyro, rows[:, 1:4]])
        self._accel = np.concatenate([self._accel, rows[:, 4:7]])
        self._arrival = np.concatenate([self._arrival, rows[:, 7]])

    def forget(self, rows: int) -> None:
        """Drop the first ``rows`` rows (``Growing.forget``)."""
        rows = min(max(rows, 0), self.n)
        self._t, self._gyro, self._accel, self._arrival = (
            a[rows:] for a in (self._t, self._gyro, self._accel, self._arrival))
        self.forgotten += rows
