"""The Q cutoff's evidence page (ilcforce.theory.q_evidence): where in the lifted check's rho the long runs
turn unbounded, on constructed rows whose answer is known (the page's numbers come from `make long`)."""

from __future__ import annotations

import math

import pandas as pd

from ilcforce.theory import q_evidence


def _row(method, rho, unbounded, bounded, experiment="paper"):
    seeds = unbounded + bounded
    truth = "unbounded" if unbounded == seeds else "bounded" if bounded == seeds else "mixed"
    return {"experiment": experiment, "method": method, "rho": rho, "unbounded": unbounded, "bounded": bounded,
            "slow": 0, "seeds": seeds, "truth": truth}


def test_the_boundary_is_the_largest_bounded_and_the_smallest_unbounded_rho():
    table = pd.DataFrame([_row("c2-robust", 0.84, 0, 3), _row("c2-robust", 0.93, 0, 3), _row("c2-robust", 0.97, 3, 0),
                          _row("c2-robust", 0.99, 2, 1),  # mixed: an unbounded seed counts against a margin
                          _row("pd-ilc", 0.50, 0, 3), _row("pd-ilc", 0.60, 3, 0), _row("pd-ilc", 0.55, 0, 3),
                          _row("c3-robust", 1.58, 0, 3), _row("c3-robust", 0.90, 3, 0)])
    edges = q_evidence.boundary(table).set_index("method")
    assert edges.loc["c2-robust", ["largest rho, bounded", "smallest rho, unbounded"]].tolist() == [0.93, 0.97]
    assert bool(edges.loc["c2-robust", "separated"])
    assert edges.loc["pd-ilc", "largest rho, bounded"] == 0.55
    # rho does not order C3-robust's cases: a bounded setting above an unbounded one
    assert not edges.loc["c3-robust", "separated"]


def test_a_method_with_only_bounded_settings_has_no_unbounded_edge():
    edges = q_evidence.boundary(pd.DataFrame([_row("c2-robust", 0.84, 0, 3)]))
    assert math.isnan(edges.loc[0, "smallest rho, unbounded"]) and edges.loc[0, "separated"] is None


def test_without_stored_sets_the_command_says_so_and_writes_nothing(tmp_path, capsys):
    assert q_evidence.main(["--results", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "no held-out growth set" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
