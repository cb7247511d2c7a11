"""The CPU split of ``python -m benchmarks.cpu``: each sampled thread counted as the right kind."""

import pytest

from benchmarks.cpu import KINDS, split


def _lines(pid, tid, dso, n):
    return [f"{pid}/{tid}  7f00deadbeef some_symbol (/x/y/{dso})"] * n


def test_threads_are_counted_by_kind():
    lines = (_lines(100, 100, "libpython3.11.so.1.0", 240)          # the parent: imports
             + _lines(101, 101, "libhdf5.so", 100) + _lines(101, 101, "libpython3.11.so.1.0", 50)  # a store
             + _lines(101, 103, "_kernels_aot.cpython-311.so", 400) + _lines(101, 103, "libm.so.6", 100)
             + _lines(101, 104, "_pcg64.cpython-311.so", 80) + _lines(101, 104, "libm.so.6", 20)  # inputs
             + _lines(105, 105, "git", 3) + _lines(105, 105, "[kernel.kallsyms]", 7)            # git
             + ["", "garbage line", "17 no-slash (x)"])
    shares, samples = split(lines)
    assert samples == 1000
    assert set(shares) == set(KINDS)
    assert shares[KINDS[0]] == pytest.approx(50.0)  # 500 of 1000 samples
    assert shares[KINDS[1]] == pytest.approx(15.0)
    assert shares[KINDS[2]] == pytest.approx(24.0)
    assert shares[KINDS[3]] == pytest.approx(10.0)
    assert shares[KINDS[4]] == pytest.approx(1.0)
    assert sum(shares.values()) == pytest.approx(100.0)


def test_no_samples_gives_zero_shares():
    assert split(["", "no samples here"]) == (dict.fromkeys(KINDS, 0.0), 0)
