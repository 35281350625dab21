"""An estimate scored from the rows ``scoredrows`` keeps gives the numbers of the whole one, to the bit."""
from dataclasses import asdict

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.scoring.broadscore import broad_measures
from mavattitude.flight import AttitudeSeries
from mavattitude.scoring.metrics import compare
from mavattitude.core.scoredrows import ScoredRows, bracket_rows


def _flight(holes, n=4000, seed=1):
    """A 200 Hz estimate (NaN rows at ``holes``, a gap of 3 s at row 2500) and a 25 Hz
    reference close to it, with a time of its own falling exactly on an estimate row."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.005 + 100.0
    t[2500:] += 3.0
    angles = np.cumsum(rng.normal(0, 0.01, (n, 3)), axis=0)
    q = quat.from_euler(angles[:, 0], angles[:, 1], angles[:, 2])
    q[holes] = np.nan
    t_ref = np.arange(95.0, t[-1] + 5.0, 0.04)
    t_ref[7] = t[1234]
    q_ref = quat.from_euler(*(np.interp(t_ref, t, angles[:, k]) + 0.02 for k in range(3)))
    return AttitudeSeries("est", t, q), AttitudeSeries("ref", t_ref, q_ref)


@pytest.mark.parametrize("holes", [[], [0, 1, 2], [500, 1023, 1024, 1025], [3999], list(range(3000, 3100)),
                                   [1024, 2047, 2048]])
def test_an_estimate_scored_from_its_kept_rows_scores_as_a_whole_one(holes):
    whole, ref = _flight(holes)
    kept = ScoredRows(bracket_rows(whole.t, ref.t))
    for a in range(0, len(whole.t), 1024):  # as the runner's steps give them
        kept.add(a, whole.q[a:a + 1024])
    part = kept.series("est", whole.t)
    assert len(part.t) < len(whole.t) / 2
    for kwargs in ({}, {"align_yaw": True, "restarts": [float(whole.t[2500])], "max_gap_s": 2.0},
                   {"exclude": [(105.0, 106.0)], "warmup_s": 3.0}, {"max_gap_s": 0.3}):
        a, b = compare(ref, whole, **kwargs), compare(ref, part, **kwargs)
        for field, value in asdict(a).items():
            if isinstance(value, np.ndarray):
                assert np.array_equal(value, asdict(b)[field], equal_nan=True), field
            else:
                assert repr(value) == repr(asdict(b)[field]), field
        assert repr(broad_measures(ref, whole, a)) == repr(broad_measures(ref, part, b))
