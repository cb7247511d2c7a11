"""The same-run policy: is a stored run the run this configuration and method would produce?

One policy, used by ``simulate --resume`` (through the store writer's ``same_run`` check) and by
``compare`` (is a store current, or stale?). A method's results depend on the common sections of
the configuration (experiment seed, plant, wall, reference, simulation, noise, surface, ... every
section that is not a method's gains) and on that method's own gains section
(``config.gains[method]``, the TOML section named after the method). They do not depend on
another method's gains, on the experiment's name or description, or on the number of
iterations (iteration j is the same whether 10 or 20 are asked for: every draw depends on
(seed, j) only). The comparison is exact and keyed by name, never by value.

Variants: ``--set`` overrides give a results folder of their own, :func:`variant_folder`, so a
variant never collides with the canonical stores of its experiment.
"""

from __future__ import annotations

import json
import re
from typing import Any

#: Keys (dotted) that do not change a method's results.
RESULT_INDEPENDENT = ("experiment.name", "experiment.description", "experiment.iterations")


def method_sections() -> tuple[str, ...]:
    """The gains sections: one per registered method."""
    from ilcforce.controllers import REGISTRY

    return tuple(REGISTRY)


def relevant(config: dict[str, Any], method: str) -> dict[str, Any]:
    """The part of a configuration (TOML layout, as a dict) that ``method``'s results depend on."""
    gains = set(method_sections()) | {method}
    out = {key: value for key, value in config.items() if key not in gains or key == method}
    out = json.loads(json.dumps(out))  # a deep copy
    for dotted in RESULT_INDEPENDENT:
        section, key = dotted.split(".")
        if isinstance(out.get(section), dict):
            out[section].pop(key, None)
    return out


def _flatten(value: Any, prefix: str, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for key in value:
            _flatten(value[key], f"{prefix}.{key}" if prefix else str(key), out)
    else:
        out[prefix] = value


def differences(stored: dict[str, Any], new: dict[str, Any], method: str) -> list[str]:
    """Dotted keys where two configurations differ in what ``method`` depends on, sorted."""
    a: dict[str, Any] = {}
    b: dict[str, Any] = {}
    _flatten(relevant(stored, method), "", a)
    _flatten(relevant(new, method), "", b)
    return sorted(key for key in set(a) | set(b)
                  if key not in a or key not in b or a[key] != b[key] or type(a[key]) is not type(b[key]))


def describe(stored: dict[str, Any], new: dict[str, Any], keys: list[str], limit: int = 4) -> str:
    """``"c3.eta (stored 5.0, new 2.0), ..."`` for the first ``limit`` keys."""
    a: dict[str, Any] = {}
    b: dict[str, Any] = {}
    _flatten(stored, "", a)
    _flatten(new, "", b)

    def short(value: Any) -> str:
        text = "<absent>" if value is _ABSENT else json.dumps(value)
        return text if len(text) <= 40 else text[:37] + "..."

    parts = [f"{k} (stored {short(a.get(k, _ABSENT))}, new {short(b.get(k, _ABSENT))})" for k in keys[:limit]]
    more = f" and {len(keys) - limit} more" if len(keys) > limit else ""
    return ", ".join(parts) + more


_ABSENT = object()


def stored_config(provenance: dict[str, Any]) -> dict[str, Any]:
    """The configuration a store was written with (its ``config_json``); {} if unreadable."""
    try:
        value = json.loads(str(provenance.get("config_json", "")))
    except json.JSONDecodeError:
        return {}
    return value if isinstance(value, dict) else {}


class DifferentRun(ValueError):
    """A stored run is not the run asked for; the message names the keys that differ."""


def check(provenance: dict[str, Any], config: dict[str, Any], method: str) -> None:
    """:class:`DifferentRun` naming the keys that differ if the stored run is not this method's run."""
    stored = stored_config(provenance)
    keys = differences(stored, config, method)
    if keys:
        raise DifferentRun(f"configuration differs from the stored run at {describe(stored, config, keys)}")


def same_run_check(config: dict[str, Any], method: str):
    """The writer's ``same_run`` callback for this configuration and method."""
    return lambda provenance: check(provenance, config, method)


# ----------------------------------------------------------------------------------------------
# variants

_UNSAFE = re.compile(r"[^A-Za-z0-9._=,+-]")
_MAX_NAME = 120


def _value_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return ",".join(_value_text(v) for v in value)
    if isinstance(value, float):  # 2, 2.0 and 2e0 are one value of a float key: one folder
        text = repr(value)
        return text[:-2] if text.endswith(".0") else text
    return str(value)


def variant_folder(experiment: str, overrides: dict[str, Any]) -> str:
    """The results folder of a variant: the experiment name and the overrides, sorted by key.

    Deterministic and filesystem-safe (letters, digits and ``._=,+-``; anything else becomes
    ``_``; a name that had to be changed or cut to 120 characters ends with a hash of the
    whole, so two different sets of overrides never share a folder).
    ``experiment.iterations`` and ``experiment.name`` never make a variant. No overrides: the
    experiment's own folder.
    """
    items = sorted((k, v) for k, v in overrides.items() if k not in ("experiment.iterations", "experiment.name"))
    if not items:
        return experiment
    text = experiment + "".join(f"--{key}={_value_text(value)}" for key, value in items)
    safe = _UNSAFE.sub("_", text)
    if safe.startswith("."):
        safe = "_" + safe[1:]
    if len(safe) > _MAX_NAME or safe != text:  # two texts must not share a folder: add a hash
        import hashlib  # only for such a name: not imported by every command

        digest = hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:10]
        safe = safe[:_MAX_NAME - 11] + "-" + digest
    return safe
