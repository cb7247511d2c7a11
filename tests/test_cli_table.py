"""The CLI's own table layout (ilcforce/cli_table.py) against rich's Table, the reference.

The summary tables of `simulate` and `compare` are laid out without rich's Table (about 20 ms
less after a run); where that layout declines, rich draws them. Either way the printed text must
be rich's, character for character, on every console width: the fast layout is compared with
rich's rendering of the same table for widths from 30 to 200 columns, both box styles, a diverged
row and a compare table of seven methods.
"""

from __future__ import annotations

import io

import pytest
from rich.console import Console

from ilcforce.cli_table import Table

HEADERS = ("j", "|e_P|_2 (m)", "|e_F|_2 (N)", "H_x (N)", "H_y (N)", "loop fallbacks", "status")


def _summary(n: int, diverged: bool, ascii_box: bool = False) -> Table:
    table = Table("paper / c3  ->  results/paper--c3.eta=2/c3.h5", ascii_box=ascii_box)
    for header in HEADERS:
        table.add_column(header, justify="right")
    for j in range(n):
        status = ("diverged at t = 1.4620 s", "red") if diverged and j == n - 1 else "complete"
        table.add_row(str(j), f"{3.54e-3 / (j + 1):.3g}", f"{3.47 / (j + 1):.3g}", "0.0184", "-", str(294 - j), status)
    return table


def _comparison(methods: int) -> Table:
    names = ("c1", "c2", "c3", "smc-bl", "pd-ilc", "c3-leak", "sl-adapt")[:methods]
    table = Table("paper: The paper's setup (the defaults of docs/model.md) (seed 0, 20 iterations)  ->  results/paper")
    table.add_column("")
    for name in names:
        table.add_column(name, justify="right")
    for label in ("iterations", "jbar_position", "position_error_2norm_j0 (m)", "divergence", "fallback_total"):
        table.add_row(label, *("none" if label == "divergence" else "1.23e-05" for _ in names))
    return table


def _printed(draw, width: int) -> str:
    buffer = io.StringIO()
    console = Console(file=buffer, width=width, force_terminal=False, color_system=None)
    draw(console)
    return buffer.getvalue()


TABLES = {
    "summary": lambda: _summary(20, False),
    "summary, diverged": lambda: _summary(8, True),
    "summary, ascii": lambda: _summary(3, False, ascii_box=True),
    "summary, one row": lambda: _summary(1, False),
    "compare, 3 methods": lambda: _comparison(3),
    "compare, 7 methods": lambda: _comparison(7),
}


@pytest.mark.parametrize("name", list(TABLES))
def test_the_layout_is_richs_on_every_width(name):
    laid_out = 0
    for width in range(30, 201, 3):
        table = TABLES[name]()
        ours = _printed(table.print, width)
        reference = _printed(lambda console: console.print(table.rich_table()), width)
        assert ours == reference, f"{name} at width {width}:\n{ours}\n---- rich ----\n{reference}"
        box = table._box().substitute(Console(width=width).options)
        laid_out += table.lines(width, box) is not None
    assert laid_out > 0, "the fast layout was never used: the comparison compared rich with itself"


def test_the_fast_layout_is_used_at_the_default_width_and_declines_what_it_cannot_draw():
    box = _summary(1, False)._box()
    assert _summary(20, False).lines(80, box) is not None  # simulate's table off a terminal
    assert _comparison(3).lines(80, box) is not None  # compare's
    assert _summary(20, False).lines(40, box) is None  # cells would wrap: rich draws it
    wide = Table("t")
    wide.add_column("x")
    wide.add_row("µ")  # not ASCII: rich measures it
    assert wide.lines(80, box) is None


def test_a_row_must_have_a_cell_per_column():
    table = Table("t")
    table.add_column("a")
    with pytest.raises(ValueError, match="1 columns"):
        table.add_row("1", "2")


def test_what_the_layout_does_not_measure_as_rich_does_goes_to_rich():
    """Found by fuzzing the layout against rich: no columns, cells with leading or trailing spaces
    (rich strips them), centred columns and columns narrowed below three characters."""
    box = _summary(1, False)._box()
    empty = Table("t")
    assert empty.lines(80, box) is None
    spaced = Table("t")
    spaced.add_column("a", justify="right")
    spaced.add_row(" 1")
    assert spaced.lines(80, box) is None
    centred = Table("t")
    centred.add_column("a", justify="center")
    centred.add_row("1")
    assert centred.lines(80, box) is None
    narrow = Table("t")
    for _ in range(12):
        narrow.add_column("a b c", justify="right")
    narrow.add_row(*([""] * 12))
    assert narrow.lines(30, box) is None
    for width in (20, 30, 40):  # and rich draws them, without raising
        for table in (spaced, centred, narrow):
            assert _printed(table.print, width) == _printed(lambda c: c.print(table.rich_table()), width)
