"""The growth test on the cases that showed it missed real instabilities (slow: about 600 iterations in
all). Each row runs the iterations a user would have run, from the first 20 (C2 at Ts = 1 ms) or 40 (the
others), and the test must say what 200-300-iteration runs show: the paper's learning laws grow (C3 and
C3-leak diverge at j = 36-209, C2's chattering grows without bound), C1 and PD-ILC stay bounded."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from ilcforce import metrics
from ilcforce.config_load import load_config
from ilcforce.experiment import simulate_iterations
from ilcforce import stability
from ilcforce.report import growth_validation

NO_NOISE = {"noise.disturbance_amplitude": 0.0, "noise.encoder": 0.0, "noise.joint_rate": 0.0,
            "noise.force_sensor": 0.0}

ROWS = [  # (case, experiment file or None for the paper's setup, overrides, method, iterations, flagged)
    ("C2, Ts = 1 ms", "experiments/ts-1ms.toml", {}, "c2", 20, True),
    ("C3, no noise source", None, NO_NOISE, "c3", 40, True),
    ("C3-leak, no noise source", None, NO_NOISE, "c3-leak", 30, True),
    ("C3, paper setup, seed 71", None, {"experiment.seed": 71}, "c3", 40, True),
    ("C3-leak, paper setup, seed 71", None, {"experiment.seed": 71}, "c3-leak", 40, True),
    ("C2, paper setup, seed 71", None, {"experiment.seed": 71}, "c2", 40, True),
    ("C1, paper setup, seed 71", None, {"experiment.seed": 71}, "c1", 40, False),
    ("PD-ILC, paper setup, seed 71", None, {"experiment.seed": 71}, "pd-ilc", 40, False),
    ("tuned C2, seed 100", "experiments/long/fivebar-tuned-error-only.toml", {"experiment.seed": 100}, "c2", 40, True),
    ("tuned C3, seed 101", "experiments/long/fivebar-tuned-error-only.toml", {"experiment.seed": 101}, "c3", 40, True),
]


@pytest.mark.slow
@pytest.mark.parametrize("case, path, overrides, method, iterations, flagged", ROWS, ids=[r[0] for r in ROWS])
def test_each_case_is_classified_as_its_long_run_shows(case, path, overrides, method, iterations, flagged):
    config = load_config(path, {**overrides, "experiment.iterations": iterations})
    k0 = metrics.settled_sample(config.simulation.sample_time)
    rows = [{**metrics.iteration_metrics(r), **metrics.memory_norms(r.memory, settled_from_sample=k0)}
            for r in simulate_iterations(config, method)]
    frame = pd.DataFrame(rows).assign(seed=config.experiment.seed, method=method)
    said, text = stability.verdict_of(frame, method, iterations, config.plant.perturbation.from_iteration,
                                     json.loads(config.to_json()))
    assert (said == stability.FLAGGED) == flagged, f"{case}: {said} ({text})"
    if flagged and not text.startswith("diverged"):
        assert "grows x" in text and "reaches 10x in" in text, text
