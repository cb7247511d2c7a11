"""Writing table frames: our own Markdown renderer, and the CSV and Markdown files of a table.

The frames come from :mod:`ilcforce.report.tables` (or any report module); headers get their unit
from ``frame.attrs["units"]``. The Markdown renderer is our own (pandas' ``to_markdown`` needs
``tabulate``, which ilcforce does not depend on). CSV keeps full precision. A user's own text put
on a page (a description) goes through :func:`inert_markdown` first.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ilcforce.report.figure_files import write_text_whole, write_whole


def is_missing(value: object) -> bool:
    """None, pd.NA or NaN (a cell shown as "–"); False for a value pd.isna cannot judge."""
    if value is None or value is pd.NA:
        return True
    try:
        return bool(pd.isna(value))
    except (TypeError, ValueError):
        return False


def format_cell(value: object, float_format: str = "{:.4g}") -> str:
    """One Markdown cell: missing -> "–", floats with ``float_format``, text with ``|`` escaped."""
    if is_missing(value):
        return "–"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return float_format.format(float(value))
    text = str(value).replace("\r", " ").replace("\n", " ")
    return text.replace("|", "\\|")


def inert_markdown(text: str) -> str:
    """A user's text (an experiment's, a study's or a tuning's description) as Markdown that shows it
    and embeds nothing: an image (``![alt](https://host/t.png)``, ``![alt](/home/me/x.png)``) and raw
    HTML (``<img src=...>``, an autolink) are escaped, so no viewer of the report's Markdown pages
    loads a file or a URL the text names (the report is read offline). Its links stay links, which a
    reader follows only by a click (the HTML page keeps only those inside the report or on the web:
    :func:`ilcforce.report.links.local_target`). Backslashes are escaped first, so none of the user's
    can undo an escape."""
    return text.replace("\\", "\\\\").replace("<", "\\<").replace("![", "!\\[")


def _is_numeric_column(column: pd.Series) -> bool:
    """Numbers only (missing values allowed), booleans excluded: right-aligned in Markdown."""
    if pd.api.types.is_bool_dtype(column):
        return False
    if pd.api.types.is_numeric_dtype(column):
        return True
    values = [v for v in column if not is_missing(v)]
    return bool(values) and all(
        isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)) for v in values
    )


def markdown_table(frame: pd.DataFrame, *, float_format: str = "{:.4g}") -> str:
    """``frame`` as a GitHub-flavoured Markdown table (no index), numbers right-aligned.

    Headers get `` [unit]`` from ``frame.attrs["units"]`` where one is given.
    """
    if len(frame.columns) == 0:
        return "(no data)\n"
    units = frame.attrs.get("units", {})
    headers = [f"{name} [{units[name]}]" if name in units else str(name) for name in frame.columns]
    aligns = ["---:" if _is_numeric_column(frame[name]) else ":---" for name in frame.columns]
    lines = [
        "| " + " | ".join(format_cell(h) for h in headers) + " |",
        "|" + "|".join(aligns) + "|",
    ]
    for row in frame.itertuples(index=False, name=None):
        lines.append("| " + " | ".join(format_cell(v, float_format) for v in row) + " |")
    return "\n".join(lines) + "\n"


def write_csv(frame: pd.DataFrame, path: Path) -> Path:
    """Write ``frame`` (no index) to ``path`` as CSV at full precision; returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_whole(path, lambda tmp: frame.to_csv(tmp, index=False))


def write_markdown(frame: pd.DataFrame, path: Path, *, title: str | None = None) -> Path:
    """Write ``frame`` as a Markdown table (under a ``# title`` if given); returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = markdown_table(frame)
    if title:
        text = f"# {title}\n\n{text}"
    return write_text_whole(path, text)


def write_table(frame: pd.DataFrame, directory: Path, stem: str, *, title: str | None = None) -> list[Path]:
    """Write ``<directory>/<stem>.csv`` and ``<stem>.md``; returns both paths."""
    return [
        write_csv(frame, directory / f"{stem}.csv"),
        write_markdown(frame, directory / f"{stem}.md", title=title),
    ]
