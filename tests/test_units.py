"""Units as users read them: every configuration key has one, and dimensionless quantities are
written one way ("1") in every table a store or a frame carries."""

from __future__ import annotations

import pytest

from ilcforce.config_load import load_config
from ilcforce.config_units import axis_label, config_unit
from ilcforce.controllers import REGISTRY
from ilcforce.metrics import METRIC_COLUMNS
from ilcforce.records import LOG_SIGNALS, REFERENCE_SIGNALS


def _keys(tree: dict, prefix: str = ""):
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from _keys(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}"


@pytest.mark.parametrize("model", ["fivebar", "serial2r"])
def test_every_configuration_key_has_a_unit(model):
    keys = list(_keys(load_config(None, {"plant.model": model}).to_dict()))
    missing = [key for key in keys if not isinstance(_unit_or_none(key), str)]
    assert not missing, f"configuration keys without a unit in ilcforce.config_units: {missing}"
    assert config_unit("simulation.sample_time") == "s" and config_unit("plant.fivebar.I3") == "kg m^2"
    assert config_unit("plant.serial2r.g") == "m/s^2" and config_unit("smc-bl.phi") == "m/s"
    assert axis_label("simulation.sample_time") == "simulation.sample_time (s)"
    assert axis_label("experiment.seed") == "experiment.seed"  # dimensionless: no "(1)" on an axis


def _unit_or_none(key):
    try:
        return config_unit(key)
    except KeyError:
        return None


def test_unknown_key_has_no_unit():
    with pytest.raises(KeyError, match="c3.nothing"):
        config_unit("c3.nothing")


def test_one_convention_for_dimensionless_units():
    units = [unit for unit, _ in METRIC_COLUMNS.values()]
    units += [unit for _axes, unit, _ in (*LOG_SIGNALS.values(), *REFERENCE_SIGNALS.values())]
    for spec in REGISTRY.values():
        units += [unit for _a, _b, unit in spec.memory_layout.values()]
        units += list(spec.gains_class.units.values())
    assert "-" not in units and all(isinstance(u, str) and u == u.strip() for u in units)
    assert METRIC_COLUMNS["iteration"][0] == METRIC_COLUMNS["fallback_count"][0] == "1"
