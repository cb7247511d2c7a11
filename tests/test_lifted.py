"""The lifted check (ilcforce.lifted, docs/model.md#lifted) as theory: what a lifted map must be.

The cases run on a short horizon (0.3 s at Ts = 1 ms, 301 samples) so that the full matrix (one
simulated iteration per column) costs about a second. What is checked: the map of a causal loop is
block lower-triangular; C2's current-iteration update does not see its own torque at the same sample
(sigma has relative degree one), so its diagonal blocks are the identity and rho = 1 exactly; a
filtered law (C2-robust's Q filter) is not triangular and its memory converges; the largest singular
value bounds every band's gain (a norm inequality); the full matrix and the matrix-free products agree;
and the predicted memory change at t = 0 is what a run's memory does there, iteration after iteration.
How well the predicted band growth matches long runs with noise is docs/lifted/validation.md (`make lifted`).
"""

import subprocess
import sys

import numpy as np
import pytest

from ilcforce.theory import lifted
from ilcforce.config_load import load_config
from ilcforce.experiment import simulate_iterations

SHORT = {"simulation.sample_time": 1e-3, "simulation.log_every": 1, "reference.duration": 0.3}


@pytest.fixture(scope="module")
def c2_full():
    return lifted.analyze(load_config(None, SHORT), "c2", at=12, full=True)


def test_c2_map_is_causal_with_identity_diagonal_blocks(c2_full):
    assert c2_full.full and c2_full.n_control == 301 and c2_full.width == 2
    assert c2_full.upper_part == 0.0  # nothing at sample l changes an update before l
    assert c2_full.causal
    assert abs(c2_full.spectral_radius - 1.0) < 1e-7  # D_l = I: rho = 1, marginal
    assert c2_full.asymptotic == "marginal (rho = 1)"


def test_largest_singular_value_bounds_every_band_gain(c2_full):
    growth = [g for _l, _h, g in c2_full.band_growth]
    assert max(growth) <= c2_full.max_singular_value * (1 + 1e-9)
    assert max(growth) > 1.0  # C2 at Ts = 1 ms: some band grows (it diverges within tens of iterations)
    assert not c2_full.bounded


def test_full_matrix_and_matrix_free_products_agree(c2_full):
    free = lifted.analyze(load_config(None, SHORT), "c2", at=12, full=False)
    for (lo_a, hi_a, g_a), (lo_b, hi_b, g_b) in zip(c2_full.band_growth, free.band_growth, strict=True):
        assert (lo_a, hi_a) == (lo_b, hi_b)
        assert abs(g_a - g_b) < 1e-4 * g_a
    assert abs(free.spectral_radius - c2_full.spectral_radius) < 1e-7
    assert free.drift_t0 == pytest.approx(c2_full.drift_t0, rel=1e-12)


def test_memory_change_at_t0_is_what_the_run_does_every_iteration(c2_full):
    cfg = lifted.noise_free(load_config(None, {**SHORT, "experiment.iterations": 15}))
    at0 = [np.concatenate([np.ravel(v)[:1] if np.ndim(v) == 1 else np.asarray(v)[0] for v in r.memory.values()])
           for r in simulate_iterations(cfg, "c2")]
    for j in (12, 13):  # the change the iteration at the linearisation point makes, and the one after
        assert at0[j] - at0[j - 1] == pytest.approx(c2_full.drift_t0, rel=1e-9, abs=1e-12)
    assert np.max(np.abs(c2_full.drift_t0)) > 0.01  # the paper's start is not consistent: it drifts
    consistent = lifted.analyze(load_config(None, {**SHORT, "simulation.initial_velocity": "consistent"}),
                                "c2", at=3, full=False)
    assert np.max(np.abs(consistent.drift_t0)) < np.max(np.abs(c2_full.drift_t0))


def test_filtered_law_is_not_triangular_and_converges():
    check = lifted.analyze(load_config(None, SHORT), "c2-robust", at=12, full=True)
    assert not check.causal  # the Q filter spreads a sample's change over the iteration
    assert check.spectral_radius < 1.0
    assert all(g < 1.0 for _l, _h, g in check.band_growth)


def test_a_method_without_memory_and_bad_bands_are_one_line_each():
    for args, words in ((["-m", "c1"], "learns nothing"), (["--bands", "a,b"], "--bands")):
        proc = subprocess.run([sys.executable, "-m", "ilcforce", "analyze", *args], capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr
        assert words in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_analyze_prints_the_check():
    proc = subprocess.run([sys.executable, "-m", "ilcforce", "analyze", "-m", "c2",
                           *[a for k, v in SHORT.items() for a in ("--set", f"{k}={v}")]],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    for words in ("spectral radius 1.000000 (marginal", "largest singular value", "predicted unbounded",
                  "memory change at t = 0"):
        assert words in proc.stdout, proc.stdout


def test_the_noise_step_is_a_small_step_for_a_smooth_law_and_a_describing_function_for_a_switch():
    """C2 is smooth: the noise-sized step gives the small step's band growth. C3's alpha_hat sgn(sigma) is a
    switch: its secant gain grows as the step shrinks (4 alpha / (pi A)), so the tiny step predicts more growth
    than the amplitude the noise really perturbs the memory at."""
    cfg = load_config(None, SHORT)
    smooth = [lifted.analyze(cfg, "c2", at=12, full=False, step=s).band_growth for s in (1e-6, "noise")]
    for (_l, _h, a), (_l2, _h2, b) in zip(*smooth, strict=True):
        assert abs(a - b) < 1e-3 * a
    paper_grid = load_config(None, {"reference.duration": 0.1})  # Ts = 0.1 ms, where the switch dominates
    tiny, noise = (max(g for _l, _h, g in lifted.analyze(paper_grid, "c3", at=12, full=False, step=s).band_growth)
                   for s in (1e-6, "noise"))
    assert tiny > 10 * noise  # 131 against 1.37 per iteration, measured
    assert noise < 2
