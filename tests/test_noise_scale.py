"""noise.scale: one factor on every noise source (docs/model.md#noise), validated, stored and reported."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcforce import store
from ilcforce.cli.main import app
from ilcforce.config_units import config_unit
from ilcforce.noise import NoiseModel, disturbance, draw_iteration
from ilcforce.report import claims


def test_scale_multiplies_every_source_and_one_changes_nothing() -> None:
    base = NoiseModel()
    t = np.linspace(0.0, 2.0, 201)
    reference = draw_iteration(3, 4, 50, base)
    same = draw_iteration(3, 4, 50, dataclasses.replace(base, scale=1.0))
    # 1 is the identity bit for bit, so stores made before the key existed are unchanged
    assert np.array_equal(reference.sensor, same.sensor)
    assert np.array_equal(disturbance(t, reference, base), disturbance(t, same, base))
    half = dataclasses.replace(base, scale=0.5)
    drawn = draw_iteration(3, 4, 50, half)
    # the same unit draws, scaled: encoder, joint rate and force sensor columns alike
    np.testing.assert_allclose(drawn.sensor, 0.5 * reference.sensor, rtol=1e-15, atol=0.0)
    assert np.array_equal(drawn.frequency, reference.frequency) and np.array_equal(drawn.phase, reference.phase)
    np.testing.assert_allclose(disturbance(t, drawn, half), 0.5 * disturbance(t, reference, base), rtol=1e-15)
    zero = dataclasses.replace(base, scale=0.0)
    assert not draw_iteration(3, 4, 50, zero).sensor.any()
    assert not disturbance(t, draw_iteration(3, 4, 50, zero), zero).any()


@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_a_bad_scale_is_refused_by_the_model(value: float) -> None:
    with pytest.raises(ValueError, match="noise.scale"):
        NoiseModel(scale=value)


@pytest.mark.parametrize(("text", "expected"), [("-1", "noise.scale must be in [0, 1e+06]"),
                                                ("nan", "noise.scale must be finite"),
                                                ("inf", "noise.scale must be finite")])
def test_a_bad_scale_is_one_line_and_exit_2(text: str, expected: str) -> None:
    result = CliRunner().invoke(app, ["config", "--set", f"noise.scale={text}"])
    output = result.output.strip()
    assert result.exit_code == 2, output
    assert expected in output and len(output.splitlines()) == 1 and "Traceback" not in output, output


def test_scale_is_stored_and_reported_like_every_key(tmp_path) -> None:
    runner = CliRunner()
    shown = runner.invoke(app, ["config", "--set", "noise.scale=0.25"])
    assert shown.exit_code == 0 and "scale = 0.25" in shown.output, shown.output
    assert config_unit("noise.scale") == "1"
    out = tmp_path / "c2.h5"
    result = runner.invoke(app, ["simulate", "-m", "c2", "--iters", "1", "--out", str(out),
                                 "--set", "reference.duration=0.05", "--set", "noise.scale=0.25"])
    assert result.exit_code == 0, result.output
    assert '"scale": 0.25' in store.read_provenance(out)["config_json"]


def test_scale_zero_is_deterministic() -> None:
    assert claims.is_deterministic({"noise": {"scale": 0.0, "encoder": 1e-6}})
    assert not claims.is_deterministic({"noise": {"scale": 0.5, "encoder": 1e-6}})
