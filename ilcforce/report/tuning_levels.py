"""The tuning page's comparison at equal chattering: every method's held-out front read at the same
settled chattering (:mod:`ilcforce.tune.levels`), at the tuning's cap and at fixed fractions of it, and,
on the paper's robot, at the paper's own chattering (Table 3's H of C1 and of C3), written as
``equal_chattering.csv`` and as one ranking line per level in the page.

``python -m ilcforce.report.tuning_levels PAGE_FOLDER TUNED_FILE`` rewrites them for a committed page
(``docs/tuning/<name>/``) from its ``pareto.csv`` and the tuned experiment file its tuning wrote (which
holds the cap), without the tuning store; ``make tune`` writes them with the rest of the page.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from ilcforce.tune.levels import ENDS_BELOW, NO_POINT, NOT_REACHED, ON_FRONT, level_table

#: The fractions of the tuning's cap each front is read at.
FRACTIONS = (1.0, 0.5, 0.25)
#: The heading of the page's section (replaced whole when the section is rewritten).
HEADING = "## At equal chattering: every front read at the same settled H"


def caps(model: str, axes: Sequence[str], cap: Sequence[float], reference: str) -> list[tuple]:
    """The caps a tuning's fronts are read at: (name, one H per axis in N, fractions). The tuning's own
    cap at :data:`FRACTIONS`; on the paper's robot with a planar task, also Table 3's H of C1 and of C3
    (the paper's chattering, at j = 20) at 1x."""
    from ilcforce.plants import DEFAULT_MODEL
    from ilcforce.report.paper import TABLE3

    out = [(f"{reference} (the tuning's cap)", tuple(float(c) for c in cap), FRACTIONS)]
    if model == DEFAULT_MODEL and tuple(axes) == ("x", "y"):
        out += [(f"Table 3 {row.method.upper()}", (row.task_x, row.task_y), (1.0,)) for row in TABLE3]
    return out


def _level(rows: pd.DataFrame, axes: Sequence[str]) -> str:
    first = rows.iloc[0]
    return (f"{first['fraction']:g} x {first['cap']} ("
            + ", ".join(f"H_{a} {first[f'level H_{a}']:.3g} N" for a in axes) + ")")


def rankings(table: pd.DataFrame, axes: Sequence[str]) -> list[str]:
    """One line per level of :func:`ilcforce.tune.levels.level_table`: the methods on their front there,
    by error objective (lowest first), then those whose front ends below the level (their high end: its
    error objective and chattering / level), those that never chatter that little, those with no stable
    point."""
    lines = []
    for _key, rows in table.groupby(["cap", "fraction"], sort=False):
        on = rows[rows["status"] == ON_FRONT].sort_values("error objective")
        below = rows[rows["status"] == ENDS_BELOW].sort_values("nearest error objective")
        above = rows[rows["status"] == NOT_REACHED]
        none = rows[rows["status"] == NO_POINT]
        parts = [", ".join(f"{r['method']} {r['error objective']:.2f}" for _i, r in on.iterrows())
                 or "no method's front reaches it"]
        if len(below):
            parts.append("front ends below it: " + ", ".join(
                f"{r['method']} ({r['nearest error objective']:.2f} at {1 / r['distance (x)']:.2f}x the level)"
                for _i, r in below.iterrows()))
        if len(above):
            parts.append("never this little: " + ", ".join(
                f"{r['method']} (least {r['distance (x)']:.2f}x the level)" for _i, r in above.iterrows()))
        if len(none):
            parts.append("no stable point: " + ", ".join(none["method"]))
        lines.append(f"- at {_level(rows, axes)}: " + "; ".join(parts) + ".")
    return lines


def section(table: pd.DataFrame, axes: Sequence[str], command: str | None = None) -> list[str]:
    """The page's markdown section: what is read, one ranking line per level, the CSV."""
    return [HEADING, "",
            "The shipped point of each method is its most accurate one under the cap, so shipped methods sit at "
            "different chattering. Here every method's held-out front (its stable points that no other of its "
            "stable points beats on both) is read at the same settled H at the last held-out iteration: the "
            "error objective log10(e_P / 1 mm) + log10(e_F / 1 N) by linear interpolation along the front in "
            "(H / cap, error objective) between the two measured points around the level (lower is better). "
            "A front that ends below a level is given at its high end, a point with less chattering than the "
            "level; an interpolated value is a read-off between two measured points, not a point run itself. "
            "Table 3's H is the paper's C1 and C3 at j = 20 on its own model (our C1 chatters about ten times "
            "more in Y at the paper's gains: docs/model.md, C1's chattering in Y); our H here is the settled H "
            "at j = 59.", "",
            *rankings(table, axes), "",
            "Every level and method, with the front points around each value: [equal_chattering.csv]"
            "(equal_chattering.csv)" + (f" (`{command}`)." if command else "."), ""]


def write_levels(target: Path, pareto: pd.DataFrame, methods: Sequence[str], axes: Sequence[str],
                 cap_list: Sequence[tuple], command: str | None = None) -> tuple[list[Path], list[str]]:
    """``equal_chattering.csv`` in ``target`` and the page section's lines."""
    from ilcforce.report.table_write import write_table

    table = level_table(pareto, methods, axes, cap_list)
    return write_table(table, target, "equal_chattering"), section(table, axes, command)


def replace_section(text: str, lines: list[str]) -> str:
    """``text`` (a page) with its :data:`HEADING` section (up to the next ``## `` heading or the end)
    replaced by ``lines``, or with ``lines`` appended when it has none."""
    before, found, after = text.partition(HEADING)
    rest = after.split("\n## ", 1)
    tail = ("\n## " + rest[1]) if found and len(rest) > 1 else ""
    return before.rstrip("\n") + "\n\n" + "\n".join(lines) + tail


def main(argv: list[str] | None = None) -> int:
    import argparse
    import tomllib

    from ilcforce.plants import DEFAULT_MODEL
    from ilcforce.records import task_axes
    from ilcforce.report.figure_files import write_text_whole

    parser = argparse.ArgumentParser(prog="python -m ilcforce.report.tuning_levels",
                                     description="read a committed tuning page's fronts at equal chattering")
    parser.add_argument("page", type=Path, help="the page's folder (docs/tuning/<name>/, with pareto.csv)")
    parser.add_argument("tuned", type=Path, help="the tuned experiment file the tuning wrote ([tuning] cap)")
    args = parser.parse_args(argv)
    try:
        pareto = pd.read_csv(args.page / "pareto.csv")
        with args.tuned.open("rb") as handle:
            tuned = tomllib.load(handle)
        tuning = tuned["tuning"]
        cap = [float(c) for c in tuning["cap"]]
        axes = task_axes(len(cap))
        model = str(tuned.get("plant", {}).get("model", DEFAULT_MODEL))
        index = args.page / "index.md"
        page = index.read_text(encoding="utf-8")
        methods = list(dict.fromkeys(pareto["method"]))
        command = f"python -m ilcforce.report.tuning_levels {args.page} {args.tuned}"
        files, lines = write_levels(args.page, pareto, methods, axes,
                                    caps(model, axes, cap, str(tuning.get("cap_reference", "the reference"))),
                                    command)
    except KeyError as error:
        print(f"error: {error} missing: the tuned file needs [tuning] cap, pareto.csv the columns of a tuning page's",
              file=sys.stderr)
        return 2
    except (OSError, ValueError, TypeError, tomllib.TOMLDecodeError, pd.errors.ParserError) as error:
        print(f"error: {' '.join(str(error).split())}", file=sys.stderr)
        return 2
    write_text_whole(index, replace_section(page, lines))
    print("\n".join(line for line in lines if line.startswith("- at ")))
    print(f"wrote {len(files) + 1} files under {args.page}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
