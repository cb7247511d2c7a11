"""ilcforce.stats: intervals whose coverage and edge cases are checked, not assumed."""

import math

import numpy as np
import pytest

from ilcforce.stats import Interval, format_interval, frequency_interval, growth_rate, median_interval


def test_median_interval_covers_true_median_at_about_the_stated_rate():
    # 200 samples of 30 from a lognormal (true median 1): a 95% interval should miss rarely.
    # The percentile bootstrap of a median undercovers a little at n = 30, so allow 88-100%.
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(200):
        iv = median_interval(rng.lognormal(size=30), n_boot=500)
        hits += iv.low <= 1.0 <= iv.high
    assert 0.88 <= hits / 200 <= 1.0, hits


def test_median_interval_drops_nan_and_is_reproducible():
    x = np.array([1.0, 2.0, np.nan, 3.0, np.inf])
    a, b = median_interval(x), median_interval(x)
    assert a == b and a.n == 3 and a.estimate == 2.0
    assert median_interval([np.nan]).n == 0 and math.isnan(median_interval([]).estimate)
    assert median_interval([4.0]) == Interval(4.0, 4.0, 4.0, 1)


def test_wilson_interval_known_values():
    # Wilson 95% for 0 of 5 is [0, 0.434]; for 97 of 100 about [0.915, 0.990] (standard tables)
    iv = frequency_interval(0, 5)
    assert iv.low == 0.0 and iv.high == pytest.approx(0.4345, abs=1e-3)
    iv = frequency_interval(97, 100)
    assert iv.low == pytest.approx(0.9155, abs=1e-3) and iv.high == pytest.approx(0.9897, abs=1e-3)
    with pytest.raises(ValueError):
        frequency_interval(6, 5)


def test_growth_rate_recovers_a_geometric_rate_and_rejects_flat_series():
    rng = np.random.default_rng(2)
    series = 1.4 ** np.arange(20) * np.exp(rng.normal(0, 0.1, 20))
    iv = growth_rate(series, last=10)
    assert iv.low < 1.4 < iv.high and iv.low > 1.0
    flat = growth_rate(1.0 + rng.normal(0, 0.01, 20))
    assert flat.low < 1.0 < flat.high
    assert math.isnan(growth_rate([1.0, -1.0, np.nan]).estimate)


def test_format_interval():
    assert format_interval(Interval(1.234, 1.0, 1.5, 10)) == "1.23 [1, 1.5]"
    assert format_interval(Interval(math.nan, math.nan, math.nan, 0)) == "-"
