"""``python -m benchmarks.floor``: the bound's arithmetic, and writers that write what they claim."""

from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from benchmarks.cold import loops_ideal
from benchmarks.floor import LAYOUTS, least_wall, main, report
from benchmarks.floor_writes import stack, write_bare, write_one_per_iteration, write_per_signal


def _records(n=3):
    rng = np.random.default_rng(5)
    return [SimpleNamespace(iteration=i, log={"time": rng.random(7), "torque": rng.random((7, 2))},
                            memory={"v": rng.random((11, 2)), "alpha_hat": rng.random(11)} if i else {})
            for i in range(n)]


def test_the_bound_is_the_work_over_the_cores_or_the_longest_loop():
    loops = {"c1": 0.30, "c2": 0.30, "c3": 0.34}
    rest = {"c1": 0.10, "c2": 0.10, "c3": 0.12}
    assert least_wall(0.08, loops, rest, 2) == pytest.approx(0.08 + 1.26 / 2)
    assert least_wall(0.08, loops, rest, 8) == pytest.approx(0.08 + 0.34)  # c3's iterations, one after another
    assert loops_ideal(loops, 2) == pytest.approx(0.47)
    assert loops_ideal(loops, 8) == pytest.approx(0.34)


def test_report_says_over_or_within_the_target():
    parts = {"start": 0.08, "loop": {"c1": 0.30, "c2": 0.30, "c3": 0.34},
             "inputs": {"c1": 0.04, "c2": 0.04, "c3": 0.04},
             "write": {LAYOUTS[0]: {"c1": 0.06, "c2": 0.06, "c3": 0.08},
                       LAYOUTS[1]: {"c1": 0.0, "c2": 0.0, "c3": 0.0},
                       LAYOUTS[2]: {"c1": 0.0, "c2": 0.0, "c3": 0.0}}}
    lines = report(parts, 2)
    # per signal: 0.08 + (0.94 + 0.12 + 0.20) / 2 = 0.71 s against 0.47 s of loops: 34%
    assert any("per signal" in line and "at least 34%" in line and "over the target" in line for line in lines)
    # nothing but inputs: 0.08 + 1.06 / 2 = 0.61 s: 23%
    assert any("bare bytes" in line and "at least 23%" in line and "within the target" in line for line in lines)
    # simulate: its inputs and writes beside its loop on the second core: 0.08 + 0.34 s, 19%
    assert any("simulate --method c3" in line and "least wall 0.420 s" in line and "at least 19%" in line
               for line in lines)


def test_per_signal_writes_every_array_with_its_units(tmp_path):
    records = _records()
    write_per_signal(tmp_path / "s.h5", records)
    with h5py.File(tmp_path / "s.h5", "r") as f:
        for record in records:
            group = f[f"iterations/{record.iteration:04d}"]
            for kind, arrays in (("log", record.log), ("memory", record.memory)):
                for name, values in arrays.items():
                    assert np.array_equal(group[f"{kind}/{name}"][()], values)
                    assert group[f"{kind}/{name}"].attrs["units"] == "-"


def test_one_per_iteration_holds_the_same_numbers_stacked(tmp_path):
    records = _records()
    write_one_per_iteration(tmp_path / "o.h5", stack(records))
    with h5py.File(tmp_path / "o.h5", "r") as f:
        for record in records:
            group = f[f"iterations/{record.iteration:04d}"]
            log = group["log"][()]
            assert np.array_equal(log[:, 0], record.log["time"]) and np.array_equal(log[:, 1:], record.log["torque"])
            assert ("memory" in group) == bool(record.memory)
            if record.memory:
                assert np.array_equal(group["memory"][()], np.column_stack([record.memory["v"],
                                                                             record.memory["alpha_hat"]]))


def test_bare_bytes_are_every_array_in_order(tmp_path):
    records = _records()
    write_bare(tmp_path / "b.bin", records)
    expected = b"".join(np.ascontiguousarray(a).tobytes() for r in records
                        for a in [*r.log.values(), *r.memory.values()])
    assert (tmp_path / "b.bin").read_bytes() == expected


@pytest.mark.parametrize("flag, value", [("--repeat", "0"), ("--iters", "-2"), ("--cores", "two")])
def test_a_count_below_one_is_one_line_not_a_traceback(flag, value, capsys):
    with pytest.raises(SystemExit) as stop:
        main([flag, value])
    assert stop.value.code == 2
    assert f"argument {flag}: expected a whole number of at least 1, got {value!r}" in capsys.readouterr().err
