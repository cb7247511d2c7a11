"""``[[study.settings]]``: an explicit list of named settings.

A full factorial ``[study.sweep]`` cannot express "none, the disturbance alone, each sensor noise
alone, all": six settings out of the sixteen on/off combinations. A settings list names exactly the
settings to run::

    [[study.settings]]
    label = "none"                            # optional; shown in the report and the tidy table
    "noise.disturbance_amplitude" = 0.0
    "noise.encoder" = 0.0
    [[study.settings]]
    label = "all"                             # no keys: the experiment (with [study.set]) as it is

Each entry is a set of overrides on top of the experiment file and ``[study.set]``, exactly as
``--set``. Entries may name different keys: the study's setting columns are the union of the keys
(first appearance order), and a setting that leaves a key alone carries the experiment's value in
that column, so the tidy table stays tidy. With a ``[study.sweep]`` as well, every listed setting is
combined with every point of the sweep (settings x sweep, the listed setting varying slowest).

Refused, each with one line: an empty list, an entry that is not a table, a nested table, a key
``experiment.seed`` (``study.seeds`` owns it), a key also in ``[study.set]`` or ``[study.sweep]``,
two entries with the same label, and two entries that resolve to the same configuration. Unknown
keys and bad values are reported by the config loader (with a did-you-mean), prefixed with the
entry they came from.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The key of an entry that is its label, not a config override.
LABEL_KEY = "label"


class SettingsListError(ValueError):
    """A malformed settings list; one line (the study wraps it as a StudyError)."""


@dataclass(frozen=True)
class ListedSetting:
    """One ``[[study.settings]]`` entry: its position, label (None when not given) and overrides."""

    position: int
    label: str | None
    overrides: dict

    def where(self) -> str:
        """``study.settings[2] ("encoder only")``: how an error message names the entry."""
        return f"study.settings[{self.position}]" + (f" ({self.label!r})" if self.label is not None else "")


def parse_settings_list(value, *, fixed: dict, sweep: dict) -> tuple[ListedSetting, ...]:
    """Check the raw ``study.settings`` value (a list of tables) -> its entries, in file order.

    Only the shape is checked here; the overrides are validated by loading each setting's config.
    """
    if not isinstance(value, list):
        raise SettingsListError("study.settings must be a list of tables: write each setting as "
                                "[[study.settings]] followed by its \"section.key\" = value lines")
    if not value:
        raise SettingsListError("study.settings is an empty list; list at least one setting or leave it out")
    entries: list[ListedSetting] = []
    labels: dict[str, int] = {}
    for position, entry in enumerate(value):
        if not isinstance(entry, dict):
            raise SettingsListError(f"study.settings[{position}] must be a table of \"section.key\" = value, "
                                    f"got {entry!r}")
        label = entry.get(LABEL_KEY)
        if label is not None and (not isinstance(label, str) or not label.strip()):
            raise SettingsListError(f"study.settings[{position}].label must be a non-empty string, got {label!r}")
        listed = ListedSetting(position, label.strip() if label is not None else None,
                               {k: v for k, v in entry.items() if k != LABEL_KEY})
        for key, item in listed.overrides.items():
            if isinstance(item, dict):
                raise SettingsListError(f"{listed.where()}: write keys as quoted dotted names, e.g. "
                                        f"\"{key}.x\" = ..., not a table [{key}]")
            if key == "experiment.seed":
                raise SettingsListError(f"{listed.where()}: experiment.seed is set by study.seeds")
            if key in fixed:
                raise SettingsListError(f"{listed.where()}: {key} is both in [study.set] and a listed setting")
            if key in sweep:
                raise SettingsListError(f"{listed.where()}: {key} is both in [study.sweep] and a listed setting")
        if listed.label is not None:
            if listed.label in labels:
                raise SettingsListError(f"{listed.where()}: label {listed.label!r} is already used by "
                                        f"study.settings[{labels[listed.label]}]")
            labels[listed.label] = position
        entries.append(listed)
    return tuple(entries)


def column_keys(entries: tuple[ListedSetting, ...]) -> list[str]:
    """The union of the entries' keys, in order of first appearance."""
    return list(dict.fromkeys(key for entry in entries for key in entry.overrides))


def config_value(config_dict: dict, dotted: str):
    """The value at ``dotted`` ("noise.encoder") of a config's ``to_dict()`` (lists stay lists)."""
    node = config_dict
    for part in dotted.split("."):
        node = node[part]
    return node


def default_label(overrides: dict) -> str:
    """The label of an unlabelled entry: its overrides as ``key=value``, or ``"base"``."""
    return ", ".join(f"{k}={v!r}" for k, v in overrides.items()) or "base"
