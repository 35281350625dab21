"""Diagnostics kept as runs or rows (mavattitude.diagcolumns): given back to the bit."""
import numpy as np

from mavattitude.diagcolumns import MIN_ROWS, Column, Series, only


def _kept(values: np.ndarray, chunk: int) -> Column:
    column = Column(values.dtype, len(values))
    for a in range(0, len(values), chunk):
        column.extend(values[a:a + chunk])
    return column


def test_runs_give_back_every_bit():
    rng = np.random.default_rng(1)
    slow = np.repeat(rng.normal(size=500).astype(np.float32), 40)  # a bias at a compass's rate
    slow[::97] = np.nan
    slow[5:9] = -0.0  # -0.0 and 0.0 are kept apart
    slow[9:12] = 0.0
    column = _kept(slow, 1000)
    assert column._rows is None and column.nbytes < slow.nbytes / 4
    out = column.series()
    assert out.dtype == np.float32 and np.array_equal(out.view(np.uint32), slow.view(np.uint32))


def test_a_series_that_changes_every_row_is_kept_row_by_row():
    rng = np.random.default_rng(2)
    fast = rng.normal(size=3 * MIN_ROWS).astype(np.float32)
    fast[:MIN_ROWS // 2] = np.nan  # rows before the key first appeared
    column = _kept(fast, 777)
    assert column._rows is not None
    assert np.array_equal(column.series().view(np.uint32), fast.view(np.uint32))


def test_codes_and_the_lazy_mapping():
    codes = np.repeat(np.array([0, 1, 2, 0], np.int8), 1000)
    series = Series({"accel_state": _kept(codes, 300), "x": _kept(np.zeros(4000, np.float32), 4000)})
    assert list(series) == ["accel_state", "x"] and "x" in series
    assert np.array_equal(series["accel_state"], codes) and series["accel_state"].dtype == np.int8
    assert list(only(series, ["x"])) == ["x"] and list(only({"a": 1, "b": 2}, ["b"])) == ["b"]
