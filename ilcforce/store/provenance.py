"""Provenance helpers of the writer: text HDF5 can store, UTC time, the git state, and the
default same-run check (the experiment layer's policy, :mod:`ilcforce.samerun`, replaces it)."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ilcforce.store.safeio import StoreError

#: A check of a stored run before resuming it: given its provenance, raise StoreError if it is
#: not the same run (the experiment layer's same-run policy supplies it).
SameRunCheck = Callable[[dict[str, Any]], None]


def text(value: object) -> str:
    """A string HDF5 can store as UTF-8: undecodable bytes of a path or argument (surrogate
    escapes, e.g. a non-ASCII file name under an ASCII locale) become U+FFFD."""
    return str(value).encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def git_state() -> tuple[str, bool]:
    """(``git rev-parse HEAD``, tree has uncommitted changes) of the package's checkout; ("", False)."""
    where = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True,
                              timeout=10, check=False)
        commit_id = head.stdout.strip()
        if head.returncode != 0 or not commit_id or any(c not in "0123456789abcdef" for c in commit_id):
            return "", False
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
                                capture_output=True, text=True, timeout=10, check=False)
        return commit_id, bool(status.stdout.strip()) if status.returncode == 0 else False
    except (OSError, subprocess.SubprocessError, ValueError):
        return "", False
