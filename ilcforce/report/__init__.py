"""Reports: tables, the paper's claims judged, and figures, read from the results store only.

:func:`write_report` is the entry point (``ilcforce report``); :mod:`.tables`, :mod:`.claims`
and :mod:`.figures` work on DataFrames and Axes (:mod:`.table_write` writes the tables as CSV and
Markdown), :mod:`.paper` holds the published numbers.
"""

__all__ = ["ReportSummary", "write_report"]


def __getattr__(name: str):
    """``write_report`` and ``ReportSummary`` on first use: ``ilcforce compare`` imports
    ``ilcforce.report.tables`` and must not pay for matplotlib (imported by ``build``)."""
    if name in __all__:
        from ilcforce.report import build

        return getattr(build, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
