"""The CLI's summary tables, laid out as rich lays out its Table, without rich's Table.

rich measures and renders every cell through its layout engine: about 20 ms for the 150 cells of
``ilcforce simulate``'s table, after the run (issue 12). :class:`Table` collects a title, columns
and rows of plain strings (a cell may carry a style, e.g. ``"red"``) and :meth:`Table.print` lays
them out itself when every column fits at its natural width, or with headers wrapped at spaces the
way rich narrows a table to the console (rich's own ``Table._collapse_widths``); the lines are
styled ``rich.text.Text`` printed through the console, which decides about colour. Anything else
(a cell that would wrap, a word of the title wider than the table, non-ASCII text) is drawn by
rich's Table.
``tests/test_cli_table.py`` compares the two on many widths.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence

Cell = str | tuple[str, str]  # text, or (text, rich style)


class Table:
    """A rich-like table: ``add_column(header, justify)``, ``add_row(*cells)``, ``print(console)``."""

    def __init__(self, title: str, *, ascii_box: bool = False) -> None:
        self.title = title  # shown literally (no markup)
        self.ascii_box = ascii_box
        self.headers: list[str] = []
        self.justify: list[str] = []
        self.rows: list[tuple[Cell, ...]] = []

    def add_column(self, header: str, justify: str = "left") -> None:
        self.headers.append(header)
        self.justify.append(justify)

    def add_row(self, *cells: Cell) -> None:
        if len(cells) != len(self.headers):
            raise ValueError(f"a row of {len(cells)} cells for {len(self.headers)} columns")
        self.rows.append(cells)

    # -- drawing ----------------------------------------------------------------------------

    def print(self, console) -> None:
        """Print on ``console`` (a rich Console): laid out here if it can be, else by rich."""
        box = self._box().substitute(console.options, safe=console.safe_box)
        lines = self.lines(console.width, box)
        if lines is None:
            console.print(self.rich_table())
            return
        from rich.text import Text

        text = Text("\n").join(Text.assemble(*parts, end="") for parts in lines)
        console.print(text, no_wrap=True, overflow="ignore", crop=False, soft_wrap=True)

    def _box(self):
        from rich.box import ASCII, HEAVY_HEAD

        return ASCII if self.ascii_box else HEAVY_HEAD

    def rich_table(self):
        """The same table as rich's Table (the reference, and the way for what :meth:`lines` declines)."""
        from rich.markup import escape
        from rich.table import Table as RichTable
        from rich.text import Text

        table = RichTable(title=escape(self.title), box=self._box())
        for header, justify in zip(self.headers, self.justify):  # fold, not "…": any encoding can show it
            table.add_column(escape(header), justify=justify, overflow="fold")
        for row in self.rows:
            table.add_row(*(Text(c[0], style=c[1]) if isinstance(c, tuple) else Text(c) for c in row))
        return table

    def lines(self, console_width: int, box) -> list[list[tuple[str, str]]] | None:
        """The table's lines as (text, style) parts, as rich would draw them on a console this wide,
        or None when that needs more than this layout does (see the module docstring)."""
        from rich.table import Table as RichTable

        texts = [[c[0] if isinstance(c, tuple) else c for c in row] for row in self.rows]
        every = [*self.headers, *(t for row in texts for t in row), self.title]
        if not self.headers or not all(t.isascii() and t.isprintable() and t == t.strip() for t in every):
            return None  # rich measures and strips what this layout does not
        if any(justify not in ("left", "right") for justify in self.justify):
            return None
        natural = [max([len(h), *(len(row[k]) for row in texts)]) + 2 for k, h in enumerate(self.headers)]
        room = console_width - (len(natural) + 1)
        widths = natural
        if sum(natural) > room:
            widths = RichTable._collapse_widths(natural, [True] * len(natural), room)
            if sum(widths) > room or min(widths) < 3:
                return None
        headers = []
        for k, header in enumerate(self.headers):
            if any(len(row[k]) > widths[k] - 2 for row in texts):
                return None  # a cell would wrap: rich's way
            if len(header) <= widths[k] - 2:
                headers.append([header])
                continue
            wrapped = textwrap.wrap(header, widths[k] - 2, break_long_words=False, break_on_hyphens=False)
            if any(len(part) > widths[k] - 2 for part in wrapped):
                return None
            headers.append(wrapped)
        table_width = sum(widths) + len(widths) + 1
        title = textwrap.wrap(self.title, table_width, break_long_words=False, break_on_hyphens=False)
        if any(len(line) > table_width for line in title):
            return None
        out: list[list[tuple[str, str]]] = []
        for line in title:  # each line centred over the table, as rich justifies its title
            pad = table_width - len(line)
            out.append([(" " * (pad // 2), ""), (line, "table.title"), (" " * (pad - pad // 2), "")])
        out.append([(box.get_top(widths), "")])
        height = max(len(h) for h in headers)
        for line in range(height):
            cells = []
            for k, parts in enumerate(headers):
                shown = parts[line - (height - len(parts))] if line >= height - len(parts) else ""
                cells.append((self._fit(shown, widths[k], self.justify[k]), "table.header"))
            out.append(self._joined(cells, box.head_left, box.head_vertical, box.head_right))
        out.append([(box.get_row(widths, "head"), "")])
        for index, row in enumerate(self.rows):
            last = index == len(self.rows) - 1
            left, mid, right = ((box.foot_left, box.foot_vertical, box.foot_right) if last
                                else (box.mid_left, box.mid_vertical, box.mid_right))
            cells = []
            for k, cell in enumerate(row):
                text, style = cell if isinstance(cell, tuple) else (cell, "")
                cells.append((self._fit(text, widths[k], self.justify[k]), style))
            out.append(self._joined(cells, left, mid, right))
        out.append([(box.get_bottom(widths), "")])
        return out

    @staticmethod
    def _fit(text: str, width: int, justify: str) -> str:
        inner = width - 2
        if justify == "right":
            return " " + text.rjust(inner) + " "
        if justify == "center":
            spare = inner - len(text)
            return " " + " " * (spare // 2) + text + " " * (spare - spare // 2) + " "
        return " " + text.ljust(inner) + " "

    @staticmethod
    def _joined(cells: Sequence[tuple[str, str]], left: str, vertical: str, right: str) -> list[tuple[str, str]]:
        parts: list[tuple[str, str]] = [(left, "")]
        for k, cell in enumerate(cells):
            if k:
                parts.append((vertical, ""))
            parts.append(cell)
        parts.append((right, ""))
        return parts
