"""Valid ranges of the configuration's fields, checked before any work.

Every numeric field has a range: its own entry in :data:`RANGES`, a section-wide ``section.*``
entry, or the default of its type (:data:`DEFAULT_RANGES`). Strings are printable and bounded.
A whole run's resources (working memory, integrator steps) are bounded too
(:data:`MAX_RUN_BYTES`, :data:`MAX_STEPS_PER_ITERATION`, estimated by
:func:`ilcforce.config_load.run_footprint`). Adding a config field needs an entry here only when the
default range does not fit it. The names the configuration gives folders follow one rule here too
(:func:`experiment_name_problem`: an experiment's and a study's name name folders of results and
reports; the stores read the same rule back).
"""

from __future__ import annotations

import re
from dataclasses import dataclass


def _bound(value) -> str:
    """A bound as a user would write it: an integer in full (2**63 - 1, not 9.22337e+18), a float short."""
    return str(value) if isinstance(value, int) and not isinstance(value, bool) else f"{value:g}"


@dataclass(frozen=True)
class Range:
    """The valid interval of a numeric field: low/high with open or closed ends."""

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False

    def contains(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def __str__(self) -> str:
        low, high = _bound(self.low), _bound(self.high)
        return f"{'(' if self.low_open else '['}{low}, {high}{')' if self.high_open else ']'}"


#: Ranges by dotted key; ``section.*`` covers a whole section, list entries use their list's key.
#: A field without an entry gets the default of its type (:data:`DEFAULT_RANGES`). Helpers adding
#: a config field add its range here when the default does not fit.
RANGES: dict[str, Range] = {
    "experiment.seed": Range(0, 2**63 - 1),
    "experiment.iterations": Range(1, 100_000),
    "reference.duration": Range(0, 600, low_open=True),
    "simulation.sample_time": Range(1e-6, 0.1),
    "simulation.substeps": Range(1, 100_000),
    "simulation.log_every": Range(1, 10_000_000),
    "simulation.filter_hz": Range(0, 1e7, low_open=True),
    "simulation.torque_bound": Range(0, 1e12, low_open=True),
    "wall.stiffness": Range(0, 1e12, low_open=True),
    "wall.damping": Range(0, 1e12),
    "wall.friction": Range(0, 1e3),
    "wall.friction_velocity": Range(1e-9, 1e3),  # m/s; below, v / v_eps overflows in tanh's argument
    "noise.*": Range(0, 1e6),
    "plant.perturbation.factor": Range(0, 1e6, low_open=True),
    "plant.perturbation.from_iteration": Range(0, 100_000),
}
#: Any other number: finite, magnitude at most 1e12 (floats) / 1e9 (integers).
DEFAULT_RANGES = {float: Range(-1e12, 1e12), int: Range(-10**9, 10**9)}
#: Strings: printable (newlines and tabs allowed), at most this many characters.
MAX_STRING = 4000
#: Resource limits of one run, checked before it starts.
MAX_RUN_BYTES = 2 * 1024**3  # working memory of one iteration (arrays on the control grid)
MAX_STEPS_PER_ITERATION = 10**9  # integrator steps (control samples x substeps)


def range_of(path: str, kind: type) -> Range:
    """The valid range of the field at dotted ``path`` (list indices ignored)."""
    key = path.split("[", 1)[0]
    if key in RANGES:
        return RANGES[key]
    parts = key.split(".")
    for cut in range(len(parts) - 1, 0, -1):
        wildcard = ".".join(parts[:cut]) + ".*"
        if wildcard in RANGES:
            return RANGES[wildcard]
    return DEFAULT_RANGES[kind]


#: A study's name, which names its store and its report folder: a plain file name (checked when a
#: study file is read, and again when a store is read, so that a stored name never makes a path).
STUDY_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
#: The file a report folder carries to say that ilcforce wrote it (``ilcforce report`` replaces such a
#: folder, and refuses to write into any other that is not empty).
REPORT_MARKER = ".ilcforce-report"
#: Names a results folder or a report folder holds beside the experiments' folders, so that no
#: experiment may take them (compared without case: a case-insensitive file system makes
#: ``Index.md`` the report's ``index.md``): the report's own pages and tables, its studies' and
#: tunings' folders (also the results folder's), and the default report folder ``results/report``.
RESERVED_NAMES = frozenset({"index.md", "index.html", "findings.md", "claims.csv", "stability.csv",
                            "studies", "tuning", "report", REPORT_MARKER})


def experiment_name_problem(text: object) -> str | None:
    """Why ``text`` cannot name an experiment, in words ("" never); None when it can.

    The one rule for an experiment's name, which names its results folder ``results/<name>/`` and its
    report folder ``<report>/<name>/``: a plain name (:data:`STUDY_NAME`: letters, digits, '.', '_',
    '-', at most 100 characters, starting with a letter or digit: never a path, a hidden file, a
    control character or a character a Markdown link would break on) that is not one of
    :data:`RESERVED_NAMES`. Checked where a name is read (the configuration, ilcforce.config) and
    where a stored one is (:func:`ilcforce.store.validate`)."""
    if not isinstance(text, str) or not STUDY_NAME.fullmatch(text):
        return ("is not a plain folder name (letters, digits, '.', '_', '-'; at most 100 characters, the "
                "first a letter or digit)")
    if text.casefold() in RESERVED_NAMES:
        return f"is reserved: the report and the results folder hold their own {text.casefold()} beside the experiments"
    return None
