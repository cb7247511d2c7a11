"""Reports: tables, the paper's claims judged, and figures, read from the results store only.

:func:`write_report` is the entry point (``ilcforce report``); :mod:`.tables`, :mod:`.claims`
and :mod:`.figures` work on DataFrames and Axes, :mod:`.paper` holds the published numbers.
"""

from ilcforce.report.build import ReportSummary, write_report

__all__ = ["ReportSummary", "write_report"]
