"""Experiment configuration: defaults, the shipped experiments, and one clear line per bad input."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from ilcforce.config import ConfigError
from ilcforce.config_load import config_from_dict, default_config, load_config, parse_override

# study files (a [study] table; ilcforce.study) live beside the experiments and are tested in test_study.py
EXPERIMENTS = sorted(p for p in Path("experiments").glob("*.toml") if "study" not in tomllib.loads(p.read_text()))


def test_paper_toml_is_the_embedded_default():
    assert load_config("experiments/paper.toml") == default_config()


def test_spec_defaults():
    c = default_config()
    assert c.simulation.sample_time == 1e-4 and c.simulation.log_every == 10 and c.n_log == 2001
    assert c.n_control == 20001
    assert c.surface.selection == (0.0, 1.0)  # erratum 2
    assert c.wall.force_sign == "applied"  # erratum 1
    assert len(c.gains["c3"].gamma) == 8  # erratum 3
    assert c.simulation.acceleration == "implicit"  # erratum 4
    assert c.plant.true_plant(9).m3 == c.plant.fivebar.m3 and c.plant.true_plant(10).m3 == pytest.approx(1.4 * 0.2611)


@pytest.mark.parametrize("path", EXPERIMENTS, ids=[p.stem for p in EXPERIMENTS])
def test_shipped_experiments_load(path):
    config = load_config(path)
    assert config.experiment.name == path.stem


def test_toml_round_trip():
    c = load_config("experiments/realistic.toml")
    assert config_from_dict(tomllib.loads(c.to_toml())) == c


BAD = [
    ({"c3": {"gamm": [1.0]}}, "did you mean 'gamma'"),
    ({"simulaton": {}}, "did you mean 'simulation'"),
    ({"c3": {"gamma": [1.0, 2.0]}}, "c3.gamma must have 8 entries"),
    ({"c1": {"k": [1.0]}}, "c1.k must have 2 entries"),
    ({"wall": {"stiffness": "stiff"}}, "wall.stiffness must be a number"),
    ({"wall": {"stiffness": float("inf")}}, "wall.stiffness must be finite"),
    ({"plant": {"fivebar": {"m3": -1.0}}}, "plant.fivebar.m3 must be finite and positive"),
    ({"plant": {"fivebar": {"L1": 0.0}}}, "plant.fivebar.L1 must be finite and positive"),
    ({"plant": {"serial2r": {"m2": 0.0}}}, "plant.serial2r.m2 must be finite and positive"),
    ({"plant": {"serial2r": {"g": -9.81}}}, "plant.serial2r.g must be finite and >= 0"),
    ({"plant": {"model": "scara"}}, "plant.model must be one of fivebar, serial2r"),
    ({"plant": {"model": "serial2r", "perturbation": {"parameter": "m3"}}},
     "plant.perturbation.parameter must be one of L1, L2"),
    ({"simulation": {"sample_time": 3e-4}}, "does not divide the horizon"),
    ({"simulation": {"log_every": 7}}, "log_every = 7 does not divide"),
    ({"simulation": {"substeps": 0}}, "simulation.substeps must be in [1, 100000], got 0"),
    ({"simulation": {"acceleration": "magic"}}, "simulation.acceleration must be one of"),
    ({"reference": {"x_amplitude": 0.5}}, "leaves the reachable workspace"),
    ({"simulation": {"initial_position": [2.0, 2.0]}}, "simulation.initial_position leaves the reachable"),
    ({"experiment": {"iterations": 0}}, "experiment.iterations must be in [1, 100000], got 0"),
    ({"experiment": {"iterations": 2.5}}, "experiment.iterations must be an integer"),
    ({"surface": {"selection": [1.0, 1.0]}}, "exactly one force axis"),
    ({"surface": {"selection": [1.0, 0.0]}}, "must select the wall's normal, the task's last axis (0, 1)"),
    ({"plant": {"perturbation": {"parameter": "m9"}}}, "plant.perturbation.parameter must be one of"),
    ({"noise": {"encoder": -1.0}}, "noise.encoder must be in [0, 1e+06], got -1.0"),
    ({"wall": {"force_sign": "up"}}, "wall.force_sign must be one of"),
    ({"c3": {"psi_acceleration": "guess"}}, "c3.psi_acceleration must be one of"),
    ({"wall": 3}, "[wall] must be a table"),
]


@pytest.mark.parametrize("data, message", BAD, ids=[m for _d, m in BAD])
def test_bad_config_names_the_field(data, message):
    with pytest.raises(ConfigError) as info:
        config_from_dict(data)
    text = str(info.value)
    assert message in text
    assert "\n" not in text


def test_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    empty = tmp_path / "empty.toml"
    empty.write_text("  \n")
    with pytest.raises(ConfigError, match="is empty"):
        load_config(empty)
    broken = tmp_path / "broken.toml"
    broken.write_text("[wall\nstiffness = ")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(broken)
    wrong = tmp_path / "wrong.toml"
    wrong.write_text("[wall]\nstifness = 3.0\n")
    with pytest.raises(ConfigError, match=r"wrong.toml: unknown key wall.stifness \(did you mean 'stiffness'\?\)"):
        load_config(wrong)


@pytest.mark.parametrize("text, key, message", [
    ("experiment = 3\n", "experiment.iterations",
     "e.toml: experiment = 3 is not a table ([experiment]), so experiment.iterations cannot be set"),
    ("[plant]\nperturbation = 3\n", "plant.perturbation.from_iteration",
     "e.toml: plant.perturbation = 3 is not a table ([plant.perturbation]), so "
     "plant.perturbation.from_iteration cannot be set"),
])
def test_a_value_where_the_file_needs_a_table_is_named_in_the_file(tmp_path, text, key, message):
    """`experiment = 3` in the file with `--iters` (an override) said '--set experiment.iterations:
    experiment is not a table', blaming an option the user never gave."""
    path = tmp_path / "e.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as info:
        load_config(path, {key: 2})
    assert str(info.value).endswith(message), str(info.value)
    with pytest.raises(ConfigError, match=r"^c3 = 2 is not a table"):
        load_config(None, {"c3": 2, "c3.eta": 1.0})
    with pytest.raises(ConfigError, match=r"^c3 = 2 is not a table"):  # the override's, not the file's
        load_config(path, {"c3": 2, "c3.eta": 1.0})
    good = tmp_path / "good.toml"
    good.write_text("[experiment]\niterations = 3\n[c3]\neta = 2.0\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"^c3.eta must be a number, got 'x'"):  # a bad override
        load_config(good, {"c3.eta": "x"})
    with pytest.raises(ConfigError, match=r"good.toml: c1.alpha must be a number, got 'x'"):  # the file's
        good.write_text('[c1]\nalpha = "x"\n', encoding="utf-8")
        load_config(good, {"c3.eta": 1.0})
    with pytest.raises(ConfigError) as info:  # a huge value is shortened, as in every other message
        load_config(None, {"c3": "x" * 100_000, "c3.eta": 1.0})
    assert len(str(info.value)) < 300


def test_a_study_file_given_as_an_experiment_file_says_so(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[study]\nname = "s"\nseeds = "0-1"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"s.toml: \[study\] is a study file's table, not an experiment's: run a "
                                          r"study file with `ilcforce study`"):
        load_config(path)
    with pytest.raises(ConfigError, match=r"^\[study\] is a study file's table"):  # from --set study.name=x
        load_config(None, {"study.name": "x"})


def test_overrides():
    assert parse_override("c3.eta=2") == ("c3.eta", 2)
    assert parse_override("wall.force_sign=paper") == ("wall.force_sign", "paper")
    assert load_config(None, dict([parse_override("c3.k=[1.0, 2.0]")])).gains["c3"].k == (1.0, 2.0)
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_override("c3.eta")


def _experiment_files():
    root = Path(__file__).resolve().parents[1] / "experiments"
    return sorted(p for p in root.glob("*.toml") if "[study]" not in p.read_text(encoding="utf-8"))


@pytest.mark.parametrize("path", [None, *_experiment_files()], ids=lambda p: p.stem if p else "default")
def test_config_command_prints_every_key_as_an_experiment_file_that_loads_back_the_same(tmp_path, path):
    """`ilcforce config [-c FILE] [--set ...]` prints the resolved configuration as TOML; run as an
    experiment file it gives exactly the same configuration (every key, each method's gains)."""
    from typer.testing import CliRunner

    from ilcforce.cli.main import app
    from ilcforce.controllers import REGISTRY

    args = ["config", "--set", "c3.eta=2.5", "--seed", "7"] + (["--config", str(path)] if path else [])
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    printed = tmp_path / "printed.toml"
    printed.write_text(result.stdout, encoding="utf-8")
    expected = load_config(path, {"c3.eta": 2.5, "experiment.seed": 7})
    assert load_config(printed).to_json() == expected.to_json()
    data = tomllib.loads(result.stdout)
    assert all(name in data for name in REGISTRY), "every method's gains section is listed"


def test_dump_toml_quotes_what_toml_needs():
    from ilcforce.tomlfile import dump_toml

    data = {"a": {"plain-key_1": 1, "with space": 'say "hi"\n', "x": [1.5, float("inf")], "b": True,
                  "inner": {"tiny": 1e-300}, "smile \U0001f600": "tab\t del\x7f \U0001f600 \u2028 é"}}
    text = dump_toml(data, {"a.inner": "a comment\nwith a newline\x7f and \U0001f600"})
    assert tomllib.loads(text) == data, text


def test_config_command_output_loads_back_whatever_the_user_typed(tmp_path):
    """An emoji in a --set string was written as two surrogate escapes, a newline in a --set argument
    broke the header comment, and rich turned ':smile:' into an emoji: each printed something that
    did not load back as typed (an attack, a review)."""
    from typer.testing import CliRunner

    from ilcforce.cli.main import app

    sets = ['experiment.description="smile \U0001f600 :smile: caf\u00e9"', "c3.k=[1.0,\n2.0]"]
    result = CliRunner().invoke(app, ["config", *[a for s in sets for a in ("--set", s)]])
    assert result.exit_code == 0, result.output
    printed = tmp_path / "printed.toml"
    printed.write_text(result.stdout, encoding="utf-8")
    loaded = load_config(printed)
    assert result.stdout.isascii(), "plain ASCII whatever the terminal's encoding"
    assert loaded.experiment.description == "smile \U0001f600 :smile: caf\u00e9" and loaded.gains["c3"].k == (1.0, 2.0)


def test_a_key_set_for_c3_reaches_c3_leak_unless_c3_leak_sets_it(tmp_path):
    """A method family shares its keys: C3-leak's gains extend C3's, so ``[c3] psi_acceleration``
    reaches C3-leak (realistic.toml once set it for C3 alone and C3-leak diverged at j = 0 with the
    measured acceleration docs/model.md#acceleration warns about); C3-leak's own table wins; other methods are
    untouched; an override reaches the family the same way."""
    config = config_from_dict({"c3": {"psi_acceleration": "desired", "eta": 2.0}})
    assert config.gains["c3-leak"].psi_acceleration == "desired" and config.gains["c3-leak"].eta == 2.0
    assert config.gains["c3-leak"].leakage == 0.02, "C3-leak's own keys keep their defaults"
    own = config_from_dict({"c3": {"eta": 2.0}, "c3-leak": {"eta": 3.0}})
    assert (own.gains["c3"].eta, own.gains["c3-leak"].eta) == (2.0, 3.0)
    realistic = load_config(Path(__file__).parent.parent / "experiments" / "realistic.toml")
    assert realistic.gains["c3-leak"].psi_acceleration == "desired"
    overridden = load_config(None, {"c3.psi_acceleration": "desired"})
    assert overridden.gains["c3-leak"].psi_acceleration == "desired"
    assert default_config().gains["c3-leak"].psi_acceleration == "measured"
    with pytest.raises(ConfigError, match="c3.psi_acceleration"):
        config_from_dict({"c3": {"psi_acceleration": "guessed"}})


def test_gains_are_attributes_of_the_config():
    """``config.c3`` is ``config.gains["c3"]`` for every registered method (a hyphen reads as an
    underscore), survives copy and pickle, and an unknown name is one AttributeError line."""
    import copy
    import pickle

    from ilcforce.config_load import load_config
    from ilcforce.controllers import REGISTRY

    config = load_config(None, {"c2.k": [300.0, 300.0]})
    for name in REGISTRY:
        assert getattr(config, name.replace("-", "_")) is config.gains[name]
    assert config.c2.k == (300.0, 300.0)
    assert pickle.loads(pickle.dumps(config)) == config and copy.deepcopy(config).c3 == config.c3
    with pytest.raises(AttributeError, match=r"^'Config' has no attribute 'c9' \(sections: experiment, plant"):
        config.c9


def test_a_runs_description_says_what_its_overrides_changed():
    """A run made with --set said "The paper's setup" in its store and report; its description now
    names each changed key with the value it replaced. Name, iterations and unchanged values are not
    variants; an overridden description is taken as given."""
    from ilcforce.config_load import load_config

    base = load_config(None).experiment.description
    config = load_config(None, {"c3.eta": 2, "simulation.sample_time": 2.5e-4, "experiment.iterations": 3})
    assert config.experiment.description == (f"{base}, with c3.eta = 2 (was 5), simulation.sample_time = 0.00025 "
                                              "(was 0.0001)")
    assert load_config(None, {"c3.eta": 5.0, "experiment.name": "x"}).experiment.description == base
    assert load_config(None, {"c3.eta": 2, "experiment.description": "mine"}).experiment.description == "mine"
    assert load_config(None, {"c3.eta": 2}, note_overrides=False).experiment.description == base
    serial = load_config(Path(__file__).resolve().parents[1] / "experiments" / "serial2r.toml", {"experiment.seed": 3})
    assert serial.experiment.description.endswith(", with experiment.seed = 3 (was 0)")
