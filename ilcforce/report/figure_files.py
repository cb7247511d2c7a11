"""Writing a report's files (figures, tables, pages): each written whole or not at all.

A report's pieces run in worker processes that a stop (Ctrl-C, SIGTERM) terminates at once
(:mod:`ilcforce.report.pool`), and a disk can fill in the middle of a file, so every file is
written to a temporary name beside its target and renamed over it: a stopped or failed report
leaves the previous file or the new one, never a truncated one. A failed write raises
:class:`ReportWriteError` naming the file; it ends the report (exit 2), where a figure that cannot
be drawn from its data is only a warning.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # tables use this module too, without matplotlib
    from matplotlib.figure import Figure


class ReportWriteError(OSError):
    """A report file could not be written (a full disk, a file-size limit, no permission)."""


def write_whole(path: Path, write: Callable[[Path], object]) -> Path:
    """``write(tmp)`` to a temporary name beside ``path``, then rename it over ``path``; returns
    ``path``. ReportWriteError naming ``path`` if that fails (``path`` is then as it was)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as error:
        raise ReportWriteError(error.errno, error.strerror or str(error), str(path)) from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return path


def write_text_whole(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all; returns ``path``."""
    return write_whole(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


#: Colours of a report PNG. A plot has a few colours and their anti-aliased edges; a palette of 256
#: shows it the same and made the PNGs about 3x smaller (6.1 MB -> 2.0 MB over a report's 32
#: figures), which keeps the one-page HTML report with every figure under 25 MB.
PNG_COLOURS = 256


def _write_png(fig: Figure, path: Path) -> None:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    buffer.seek(0)
    with Image.open(buffer) as image:
        palette = image.convert("RGB").quantize(colors=PNG_COLOURS, method=Image.Quantize.FASTOCTREE,
                                                dither=Image.Dither.NONE)
    palette.save(path, format="png")


def save_figure(fig: Figure, directory: Path, stem: str, formats: tuple[str, ...]) -> list[Path]:
    """Write ``<directory>/<stem>.<fmt>`` for each format, each whole or not at all; returns the
    paths. PNGs are written with a palette (:data:`PNG_COLOURS`); PDFs carry no creation date, so an
    unchanged report is byte-identical."""
    return [write_whole(Path(directory) / f"{stem}.{fmt}",
                        (lambda tmp: _write_png(fig, tmp)) if fmt == "png" else
                        (lambda tmp, fmt=fmt: fig.savefig(tmp, format=fmt,
                                                          metadata={"CreationDate": None} if fmt == "pdf" else None)))
            for fmt in formats]


def copy_committed(source: Path, target: Path, skip: frozenset[str] = frozenset()) -> list[Path]:
    """Copy the files of a committed folder of pages (``docs/tuning/<name>``, ``docs/long-run``) into the
    report folder ``target``, each whole or not at all, except those named in ``skip``; returns the
    files written (none when ``source`` is no folder: an installed package has no docs). A symlink or
    a subfolder there is not copied: the report holds what the folder itself holds."""
    import shutil

    source, written = Path(source), []
    items = sorted(source.iterdir()) if source.is_dir() else []
    for item in items:
        if item.is_file() and not item.is_symlink() and item.name not in skip:
            Path(target).mkdir(parents=True, exist_ok=True)
            written.append(write_whole(Path(target) / item.name, lambda tmp, item=item: shutil.copyfile(item, tmp)))
    return written
