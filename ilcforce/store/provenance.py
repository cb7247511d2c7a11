"""Provenance helpers of the writer: text HDF5 can store, UTC time, the git state, and the
default same-run check (the experiment layer's policy, :mod:`ilcforce.samerun`, replaces it)."""

from __future__ import annotations

import json
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


def _leaves(value: Any, prefix: str, out: dict[str, Any]) -> dict[str, Any]:
    if isinstance(value, dict):
        for key, item in value.items():
            _leaves(item, f"{prefix}.{key}" if prefix else str(key), out)
    else:
        out[prefix] = value
    return out


def default_same_run(config_json: str) -> SameRunCheck:
    """Without a policy: the stored configuration must equal this one, key by key, except
    ``experiment.iterations`` (the experiment layer's policy, :mod:`ilcforce.samerun`, is finer)."""
    def check(provenance: dict[str, Any]) -> None:
        try:
            stored = _leaves(json.loads(str(provenance["config_json"])), "", {})
            new = _leaves(json.loads(config_json), "", {})
        except json.JSONDecodeError:
            raise StoreError("the stored configuration is not valid JSON") from None
        for leaves in (stored, new):
            leaves.pop("experiment.iterations", None)
        keys = sorted(k for k in set(stored) | set(new)
                      if k not in stored or k not in new or stored[k] != new[k] or type(stored[k]) is not type(new[k]))
        if keys:
            raise StoreError(f"configuration differs from the stored run at {', '.join(keys[:6])}"
                             + (f" and {len(keys) - 6} more" if len(keys) > 6 else ""))
    return check


