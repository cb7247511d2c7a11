"""Writing a report's figure files: each format written whole or not at all.

A report's figures are drawn in worker processes that a stop (Ctrl-C, SIGTERM) terminates at once
(:mod:`ilcforce.report.pool`), so a figure is written to a temporary name beside its target and
renamed over it: a stopped report leaves the previous figure or the new one, never a truncated file.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from matplotlib.figure import Figure


def save_figure(fig: Figure, directory: Path, stem: str, formats: tuple[str, ...]) -> list[Path]:
    """Write ``<directory>/<stem>.<fmt>`` for each format (via a temporary file and a rename);
    returns the paths. PDFs carry no creation date, so an unchanged report is byte-identical."""
    written = []
    for fmt in formats:
        path = Path(directory) / f"{stem}.{fmt}"
        tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
        try:
            fig.savefig(tmp, format=fmt, metadata={"CreationDate": None} if fmt == "pdf" else None)
            os.replace(tmp, path)
        finally:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        written.append(path)
    return written
