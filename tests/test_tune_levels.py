"""Fronts read at equal chattering (ilcforce/tune/levels.py, ilcforce/report/tuning_levels.py) on synthetic
fronts whose answers are known by hand: linear interpolation is exact on a straight front, a level beyond
either end of a front says so with the nearest end and its distance, and the page's ranking lines and CSV
come from the same table."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from ilcforce.report import tuning_levels
from ilcforce.tune.levels import ENDS_BELOW, NO_POINT, NOT_REACHED, ON_FRONT, level_table, read_off

# a straight front: error = 2 - 3 x chattering at chattering 0.1, 0.3, 0.6, 1.0 (indices 0, 2, 3, 4), and a
# dominated point (index 1: more chattering and more error than index 0's neighbour on the line)
LINE = [(0.1, 1.7), (0.45, 5.0), (0.3, 1.1), (0.6, 0.2), (1.0, -1.0)]


@pytest.mark.parametrize("level, between", [(0.2, (0, 2)), (0.45, (2, 3)), (0.8, (3, 4)), (0.1, (0, 2)),
                                            (0.6, (2, 3)), (1.0, (3, 4))])
def test_interpolation_is_exact_on_a_straight_front(level, between):
    found = read_off(LINE, level)
    assert found.status == ON_FRONT and found.distance == 1.0
    # the front is a line, so linear interpolation along it must give the line's value (float round-off only)
    assert found.error == pytest.approx(2.0 - 3.0 * level, abs=1e-12), f"level {level}"
    assert found.between == between, "the front points around the level, not the dominated one"


def test_a_level_above_the_front_says_its_front_ends_below_with_the_nearest_end_and_distance():
    found = read_off(LINE, 2.5)
    assert found.status == ENDS_BELOW and math.isnan(found.error)
    assert found.nearest == 4 and found.distance == pytest.approx(2.5 / 1.0)


def test_a_level_below_the_front_is_not_reached_with_the_nearest_end_and_distance():
    found = read_off(LINE, 0.05)
    assert found.status == NOT_REACHED and math.isnan(found.error)
    assert found.nearest == 0 and found.distance == pytest.approx(0.1 / 0.05)


def test_a_one_point_front_is_read_only_at_its_point_and_no_point_says_so():
    assert read_off([(0.5, -2.0)], 0.5).error == -2.0
    assert read_off([(0.5, -2.0)], 0.6).status == ENDS_BELOW
    assert read_off([], 0.5).status == NO_POINT
    assert read_off([(math.nan, -2.0)], 0.5).status == NO_POINT, "a point without a chattering is not on a front"
    with pytest.raises(ValueError, match="positive"):
        read_off(LINE, 0.0)


def _pareto() -> pd.DataFrame:
    """Two methods on a cap of (H_x 0.1, H_y 1.0) N: "a" has a straight front from 0.2 to 1.0 of the cap
    (its chattering set by H_y on one point, by H_x on the others), "b" one stable point at 0.2 and an
    unstable one at 1.0 that must not count; "c" no stable point."""
    rows = [("a", 1, 0.01, 0.2, -1.0), ("a", 2, 0.06, 0.1, -3.0), ("a", 3, 0.1, 0.5, -5.0),
            ("b", 0, 0.02, 0.1, -4.0), ("b", 5, 0.1, 0.1, -9.0), ("c", 0, 0.05, 0.5, -2.0)]
    return pd.DataFrame([{"method": m, "trial": t, "H_x settled": hx, "H_y settled": hy, "error objective": e,
                          "stable": not (m == "b" and t == 5) and m != "c"} for m, t, hx, hy, e in rows])


def test_level_table_reads_every_method_at_every_level_relative_to_each_cap():
    caps = [("ours", (0.1, 1.0), (1.0, 0.5, 0.1)), ("half", (0.05, 0.5), (1.0,))]
    table = level_table(_pareto(), ["a", "b", "c"], ("x", "y"), caps)
    assert len(table) == 4 * 3 and list(table["method"][:3]) == ["a", "b", "c"]
    row = table[(table["cap"] == "ours") & (table["fraction"] == 0.5)].set_index("method")
    # "a" at 0.5: between trial 1 (0.2, -1) and trial 2 (0.6, -3): -1 + (0.3 / 0.4) x (-2) = -2.5
    assert row.loc["a", "status"] == ON_FRONT and row.loc["a", "error objective"] == pytest.approx(-2.5)
    assert (row.loc["a", "from trial"], row.loc["a", "to trial"]) == (1, 2)
    assert row.loc["a", "level H_x"] == pytest.approx(0.05) and row.loc["a", "level H_y"] == pytest.approx(0.5)
    # "b": its one stable point is at 0.2 (its unstable trial 5 at 1.0 with a lower error must not count)
    assert row.loc["b", "status"] == ENDS_BELOW and row.loc["b", "nearest trial"] == 0
    assert row.loc["b", "nearest chattering / level"] == pytest.approx(0.4)
    assert row.loc["b", "nearest error objective"] == -4.0 and row.loc["b", "distance (x)"] == pytest.approx(2.5)
    assert row.loc["c", "status"] == NO_POINT
    low = table[(table["cap"] == "ours") & (table["fraction"] == 0.1)].set_index("method")
    assert low.loc["a", "status"] == NOT_REACHED and low.loc["a", "distance (x)"] == pytest.approx(2.0)
    # against a cap half as large, every chattering doubles: "a" at 1x that cap is its 0.5x of ours
    half = table[table["cap"] == "half"].set_index("method")
    assert half.loc["a", "error objective"] == pytest.approx(-2.5)


def test_the_ranking_lines_order_by_error_and_name_every_method_off_its_front():
    caps = [("ours", (0.1, 1.0), (1.0, 0.5))]
    lines = tuning_levels.rankings(level_table(_pareto(), ["a", "b", "c"], ("x", "y"), caps), ("x", "y"))
    assert lines[1] == ("- at 0.5 x ours (H_x 0.05 N, H_y 0.5 N): a -2.50; front ends below it: b (-4.00 at "
                        "0.40x the level); no stable point: c.")
    assert len(lines) == 2


def test_the_paper_caps_are_read_only_on_the_papers_robot():
    mine = tuning_levels.caps("fivebar", ("x", "y"), (0.1, 0.5), "c1")
    assert [c[0] for c in mine] == ["c1 (the tuning's cap)", "Table 3 C1", "Table 3 C3"]
    assert mine[1][1] == (0.06, 0.0534) and mine[2][1] == (0.0359, 0.0219), "Table 3's H in X and Y, N"
    assert len(tuning_levels.caps("serial2r", ("x", "y"), (0.1, 0.5), "c1")) == 1


def test_a_page_section_is_appended_once_and_then_replaced():
    page = "# Tuning\n\ntext\n"
    once = tuning_levels.replace_section(page, [tuning_levels.HEADING, "", "one"])
    twice = tuning_levels.replace_section(once + "\n## Later\n\nkept\n", [tuning_levels.HEADING, "", "two"])
    assert once.count(tuning_levels.HEADING) == 1 and twice.count(tuning_levels.HEADING) == 1
    assert "one" not in twice and "two" in twice and twice.endswith("## Later\n\nkept\n")


def test_the_command_rewrites_a_committed_page_and_refuses_a_bad_file_in_one_line(tmp_path, capsys):
    folder = tmp_path / "page"
    folder.mkdir()
    _pareto().to_csv(folder / "pareto.csv", index=False)
    (folder / "index.md").write_text("# Tuning t\n", encoding="utf-8")
    tuned = tmp_path / "tuned.toml"
    tuned.write_text('[plant]\nmodel = "serial2r"\n[tuning]\ncap = [0.1, 1.0]\ncap_reference = "c1"\n')
    assert tuning_levels.main([str(folder), str(tuned)]) == 0
    table = pd.read_csv(folder / "equal_chattering.csv")
    assert len(table) == 3 * 3 and set(table["cap"]) == {"c1 (the tuning's cap)"}
    assert tuning_levels.HEADING in (folder / "index.md").read_text(encoding="utf-8")
    capsys.readouterr()
    tuned.write_text("[tuning]\n")
    assert tuning_levels.main([str(folder), str(tuned)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: 'cap' missing") and len(err.strip().splitlines()) == 1
    tuned.write_text('[tuning]\ncap = [0.1, 1.0]\n')
    _pareto().drop(columns="H_y settled").to_csv(folder / "pareto.csv", index=False)
    assert tuning_levels.main([str(folder), str(tuned)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: 'H_y settled' missing") and len(err.strip().splitlines()) == 1
    assert tuning_levels.main([str(tmp_path / "absent"), str(tuned)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
