"""C3-robust taken apart (experiments/long/c3-robust-ablation.toml, ilcforce.report.c3_robust_ablation): the
shipped study runs each of the four changes alone and left out on seeds no other study uses, and the page's
table counts divergence, errors, settled H and alpha_hat against its bound as its module doc says, on
constructed runs whose answers are known. The page's numbers come from `make long`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ilcforce.report import c3_robust_ablation as ablation
from ilcforce.study.spec import is_study_file, load_study

ROOT = Path(__file__).resolve().parents[1]
STUDY_FILE = ROOT / "experiments" / "long" / "c3-robust-ablation.toml"
CHANGES = ("learn_from", "q_cutoff", "alpha_max", "psi_acceleration")


def _on(gains) -> tuple[bool, ...]:
    return (gains.learn_from > 0, gains.q_cutoff > 0, gains.alpha_max < ablation.NO_BOUND,
            gains.psi_acceleration == "desired")


def test_the_shipped_study_runs_each_change_alone_and_left_out_all_and_none():
    study = load_study(STUDY_FILE)
    assert study.methods == ("c3-robust",) and study.seeds == (530, 531, 532, 533, 534)
    assert study.settings[0].config.experiment.iterations >= 300
    patterns = {}
    for setting in study.settings:
        g = setting.config.gains["c3-robust"]
        if g.alpha_leak == 0.0:
            patterns[_on(g)] = setting.label()
    wanted = {tuple(True for _ in CHANGES), tuple(False for _ in CHANGES)}
    for i in range(4):
        wanted.add(tuple(k == i for k in range(4)))  # alone
        wanted.add(tuple(k != i for k in range(4)))  # left out
    assert set(patterns) == wanted, patterns
    shipped = load_study(STUDY_FILE).settings[0].config.gains["c3-robust"]
    from ilcforce.config_load import load_config

    default = load_config(None).gains["c3-robust"]
    assert shipped == default, "the 'all four' setting is the shipped C3-robust"


def test_the_ablation_seeds_are_held_out_from_every_other_study():
    """Seeds 530-534 belong to the ablation alone (its 1,000-iteration leak check continues it on two of them)."""
    ours = set(load_study(STUDY_FILE).seeds)
    for path in sorted((ROOT / "experiments").rglob("*.toml")):
        if path == STUDY_FILE or not is_study_file(path):
            continue
        study = load_study(path)  # once: a study file's load builds every setting's configuration
        if study.name == ablation.LEAK_CHECK:
            continue
        assert not ours & set(study.seeds), path


class _Study:
    """What ``read_study`` returns, as far as the table reads it."""

    def __init__(self, settings: dict[str, tuple[dict, pd.DataFrame]]):
        self._frames = [frame for _c, frame in settings.values()]
        self.settings = pd.DataFrame({"setting": range(len(settings)), "label": list(settings),
                                      "config_json": [json.dumps(c) for c, _f in settings.values()]})
        self.metrics = pd.concat(self._frames, ignore_index=True)
        self.description = "constructed"
        self.sessions = []

    def setting_metrics(self, k: int) -> pd.DataFrame:
        return self._frames[k]


def _run(seed: int, n: int, alpha, *, diverge_at: int | None = None, e_f=1.0):
    rows = []
    for j in range(n):
        done = diverge_at is None or j < diverge_at
        rows.append({"seed": seed, "method": "c3-robust", "iteration": j, "status": "complete" if done else "diverged",
                     "diverged_time": math.nan if done else 0.0051,
                     "position_error_2norm": 1e-4 if done else math.nan,
                     "force_error_2norm": e_f if done else math.nan,
                     "chattering_task_x_settled": 0.02 + 1e-4 * j if done else math.nan,
                     "chattering_task_y_settled": 0.03 if done else math.nan,
                     "memory_settled_alpha_hat": alpha(j) if done else math.nan,
                     "memory_start_theta_hat": 2.0 + 0.5 * j if done else math.nan})
        if not done:
            break
    return pd.DataFrame(rows)


def _config(n, **gains):
    return {"experiment": {"iterations": n}, "c3-robust": {"learn_from": 0.005, "q_cutoff": 50.0, "alpha_max": 0.03,
                                                           "psi_acceleration": "desired", **gains}}


def test_the_table_of_constructed_runs():
    n = 80
    capped = pd.concat([_run(0, n, lambda j: min(0.03, 0.002 * j)),           # at the bound from j = 15
                        _run(1, n, lambda j: 0.001 * j, diverge_at=25, e_f=3.0),  # below it, diverges at j = 25
                        ], ignore_index=True)
    free = pd.concat([_run(0, n, lambda j: 0.002 * j, diverge_at=4), _run(1, n, lambda j: 0.002 * j, diverge_at=8)],
                     ignore_index=True)
    study = _Study({"all four": (_config(n), capped),
                    "none": (_config(n, learn_from=0.0, q_cutoff=0.0, alpha_max=1e12, psi_acceleration="measured"),
                             free)})
    table = ablation.ablation_table(study).set_index("setting")
    row = table.loc["all four"]
    assert row["changes on"] == "window, Q, bound, desired acc."
    assert row["diverged"] == "1 of 2" and row["diverged at j (median)"] == 25
    assert row["at t in the iteration (ms, median)"] == pytest.approx(5.1)
    assert row["through j=19"] == 2 and row["e_F j=15..19 (N)"] == pytest.approx(2.0)  # median of 1.0 and 3.0
    assert row[f"ran all {n}"] == 1 and row[f"H_x settled j={n - 1} (N)"] == pytest.approx(0.02 + 1e-4 * (n - 1))
    assert row["H_y settled j=19 (N)"] == pytest.approx(0.03)
    assert row[f"e_F j={n - 5}..{n - 1} (N)"] == pytest.approx(1.0)  # the seed that ran all, its last five
    assert row["at the bound"] == "1 of 2" and row["bound reached at j (median)"] == 15
    assert row["alpha_hat settled RMS, last j (N)"] == pytest.approx((0.03 + 0.024) / 2)
    assert row["alpha_max (N)"] == 0.03
    assert row[f"alpha_hat rise per iteration, j={n - 51}..{n - 1} (N)"] == 0.0  # capped since j = 15
    assert row["Theta_hat at t=0, j=19"] == pytest.approx(2.0 + 0.5 * 19)  # both seeds ran to j = 19
    assert row[f"Theta_hat at t=0, j={n - 1}"] == pytest.approx(2.0 + 0.5 * (n - 1))  # only seed 0 ran all
    none = table.loc["none"]
    assert none["changes on"] == "none" and none["diverged"] == "2 of 2" and none["diverged at j (range)"] == "4-8"
    assert none["at the bound"] == "no bound" and math.isinf(none["alpha_max (N)"])
    assert none["through j=19"] == 0 and math.isnan(none["e_P j=15..19 (m)"])


def test_the_page_is_written_from_a_stored_study_only(tmp_path):
    """No store: nothing written and exit 2 with one line; the page never touches long-run.md."""
    out = tmp_path / "out"
    assert ablation.write_page(tmp_path / "results", out) == [] and not out.exists()
    assert ablation.main(["--results", str(tmp_path / "results"), "--out", str(out)]) == 2


def test_the_profile_of_a_constructed_alpha_hat():
    alpha = np.concatenate([np.zeros(10), np.full(30, 0.03), np.linspace(0.01, 0.02, 10)])
    row = ablation.profile_row(alpha, 0.03, 10)
    assert row["share of t at the bound"] == pytest.approx(30 / 40)
    assert (row["alpha_hat min (N)"], row["alpha_hat max (N)"]) == (0.01, 0.03)
    flat = ablation.profile_row(np.full(20, 0.02), 1e12, 0)
    assert flat["variation over t (std/mean)"] < 1e-12 and math.isnan(flat["share of t at the bound"])


def test_alpha_profiles_rerun_the_study_files_cells(tmp_path):
    """A real rerun of two cells of a small study file: with a bound far below what alpha_hat learns in two
    iterations it sits at the bound over the whole settled window; without one it varies over t."""
    study = tmp_path / "tiny.toml"
    study.write_text('\n'.join([
        '[study]', 'name = "tiny"', 'methods = ["c3-robust"]', 'seeds = [530]',
        '[study.set]', '"experiment.iterations" = 2',
        '[[study.settings]]', 'label = "capped"', '"c3-robust.alpha_max" = 1e-6',
        '[[study.settings]]', 'label = "free"', '"c3-robust.alpha_max" = 1e12',
        '[[study.settings]]', 'label = "not asked for"', '"c3-robust.alpha_max" = 0.5', '']), encoding="utf-8")
    table = ablation.alpha_profiles(530, ["capped", "free"], study).set_index("setting")
    assert list(table.index) == ["capped", "free"] and set(table["j"]) == {1}
    assert table.loc["capped", "share of t at the bound"] > 0.99
    assert table.loc["capped", "alpha_hat median (N)"] == pytest.approx(1e-6, rel=1e-9)
    assert math.isnan(table.loc["free", "share of t at the bound"]) and math.isinf(table.loc["free", "alpha_max (N)"])
    assert table.loc["free", "variation over t (std/mean)"] > 0.05


def test_the_ablation_and_its_leak_check_are_long_studies_left_out_of_the_findings():
    """The report's findings leave these `make long` studies to their committed page (report.long_run)."""
    from ilcforce.report import long_run

    names = {load_study(path).name for path in (ROOT / "experiments" / "long").glob("c3-robust-*.toml")}
    assert names == {ablation.STUDY, ablation.LEAK_CHECK}
    assert all(long_run.is_long_study(name) for name in names)
    assert not long_run.is_long_study("paper-mc")
