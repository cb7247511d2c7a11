"""The shipped tuning files (experiments/tuning/*.toml) hold the rules docs/tuning.md states: a gain that
several methods share is searched on the same range in each (a method is not handed a wider or narrower
search of the same gain than its rivals), every file loads, its check and held-out horizons are at
least 3x its scored one, its three sets of seeds are disjoint, trial 0 (the shipped gains) lies in its
space, and the tuned experiment file it writes names it."""

from __future__ import annotations

import tomllib
from collections import defaultdict
from pathlib import Path

import pytest

from ilcforce.controllers import REGISTRY
from ilcforce.tune import load_tuning
from ilcforce.tune.spec import HORIZON_FACTOR

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"
FILES = sorted((EXPERIMENTS / "tuning").glob("*.toml"))
#: Tuning files that search fewer than every registered method, with exactly these (each file's header says
#: why): the spatial arm's compares NO-ILC with C3 and the robust variants, C1 the cap's reference, and
#: leaves the others out for compute. Every other file tunes every method.
SUBSETS = {"arm3-tune": {"c1", "c3", "c2-robust", "c3-robust", "no-ilc"}}


def test_there_are_tuning_files():
    assert {f.stem for f in FILES} >= {"fivebar-tune", "serial2r-tune", "arm3-tune"}
    assert set(SUBSETS) <= {f.stem for f in FILES}


def shared_gain_ranges(path: Path) -> dict[tuple[str, int], dict[str, tuple]]:
    """(field, number of elements) -> {method: its elements (a range or a fixed number, per element)}."""
    tuning = load_tuning(path)
    out: dict[tuple[str, int], dict[str, tuple]] = defaultdict(dict)
    for method, gains in tuning.gains.items():
        for gain in gains:
            out[(gain.field, len(gain.elements))][method] = gain.elements
    return out


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_a_gain_shared_by_methods_has_one_range(path):
    """Same field name and same number of elements in several methods: the same range per element."""
    differ = []
    for (field, size), by_method in shared_gain_ranges(path).items():
        if len(by_method) < 2:
            continue
        for i in range(size):
            seen = {}
            for method, elements in by_method.items():
                seen.setdefault(elements[i], []).append(method)
            if len(seen) > 1:
                differ.append(f"{field}[{i}]: " + "; ".join(f"{'/'.join(ms)}: {r}" for r, ms in seen.items()))
    assert not differ, f"{path.name}: " + " | ".join(differ)


def test_the_rule_catches_a_differing_range(tmp_path):
    """The check above fails a file where one method searches a shared gain on another range."""
    text = (EXPERIMENTS / "tuning" / "fivebar-tune.toml").read_text()
    text = text.replace('experiment = "../paper.toml"', f'experiment = "{EXPERIMENTS / "paper.toml"}"')
    at = text.index("[tune.gains.c2]")
    text = text[:at] + text[at:].replace("high = 10000.0", "high = 5000.0", 1)
    path = tmp_path / "wide.toml"
    path.write_text(text)
    with pytest.raises(AssertionError, match=r"k\[0\]: .*c2: GainRange\(low=1.0, high=5000.0"):
        test_a_gain_shared_by_methods_has_one_range(path)


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_a_shipped_tuning_file_loads_and_keeps_its_horizons_and_seeds_apart(path):
    tuning = load_tuning(path)
    assert tuning.name == path.stem
    assert set(tuning.methods) == SUBSETS.get(path.stem, set(REGISTRY))  # one rule for budgets
    assert tuning.cap_reference in tuning.methods
    assert tuning.check_iterations >= HORIZON_FACTOR * tuning.iterations
    assert tuning.heldout_iterations >= HORIZON_FACTOR * tuning.iterations
    seeds, check, heldout = set(tuning.seeds), set(tuning.check_seeds), set(tuning.heldout_seeds)
    assert not seeds & check and not seeds & heldout and not check & heldout
    for method in tuning.methods:  # the sampler learns from trial 0 (the experiment's gains)
        assert tuning.defaults_in_space(method), method


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_the_tuned_experiment_file_names_its_tuning(path):
    tuned = EXPERIMENTS / f"{path.stem.removesuffix('-tune')}-tuned.toml"
    assert tuned.is_file(), f"{path.name} writes {tuned.name} (`make tune`), which is missing"
    table = tomllib.loads(tuned.read_text()).get("tuning")
    if table is None:
        # written by the tuning before [tuning] existed (the error-only one): the next `make tune` writes it
        pytest.skip(f"{tuned.name} has no [tuning] table yet")
    assert table["source"] == load_tuning(path).name
    assert set(table.get("withheld", [])) <= set(REGISTRY)
