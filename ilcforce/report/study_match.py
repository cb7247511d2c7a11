"""Which study, if any, ran the same setup as a single-run experiment: its bands go beside the run's
figures ("bands over seeds where a study exists").

A study setting matches an experiment when, for every method the two share (at least one), the
configuration the method's results depend on (:func:`ilcforce.samerun.differences`) and the number
of iterations are the same, the seed apart: ``paper-mc`` (the paper's setup over 100 seeds) matches the ``paper`` experiment.
Only the study stores' headers are read (the settings' configurations and the study file), each
checked first by the store's time-limited probe.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ilcforce import samerun
from ilcforce.records import axis_text

#: A study's figures that have a single-run counterpart: single-run stem -> study stem (+ _s<k>).
BAND_FIGURES = {
    "fig3_position_error_norm": "fig3_position_error_norm",
    "fig4_force_error_norm": "fig4_force_error_norm",
    "fig5_tracking_error": "fig5_tracking_error_seeds",
    **{f"fig{7 if axis in ('y', 'n') else 6}_input_{axis}": f"fig{7 if axis in ('y', 'n') else 6}_input_{axis}_seeds"
       for axis in ("x", "y", "u", "v", "n")},  # the task axes of records.task_axes(2) and (3)
}


@dataclass(frozen=True)
class StudyMatch:
    """Study ``name``'s setting ``setting`` ran this experiment's configuration over ``n_seeds`` seeds
    (0 when the study file is not stored: a study built in code)."""

    name: str
    setting: int
    n_seeds: int
    methods: tuple[str, ...]
    first_seed: int | None = None  # the seed its figures draw alone (dashed)
    run_seed: int | None = None  # this experiment's seed

    def figure(self, stem: str) -> str:
        """The study report's figure for single-run figure ``stem``, relative to the run's report."""
        return f"../studies/{self.name}/{BAND_FIGURES[stem]}_s{self.setting}.png"


def study_methods_and_seeds(study_toml: str) -> tuple[tuple[str, ...] | None, tuple[int, ...]]:
    """The methods (None: not listed) and seeds of a study file's text; (None, ()) if unreadable."""
    from ilcforce.study.spec import StudyError, parse_seeds
    from ilcforce.tomlfile import parse_toml

    try:
        table = parse_toml(study_toml).get("study", {})
        seeds = parse_seeds(table.get("seeds"))
    except (tomllib.TOMLDecodeError, StudyError, AttributeError, TypeError):
        return None, ()
    methods = table.get("methods")
    return (tuple(methods) if isinstance(methods, list) else None), seeds


def _latest_study_toml(header: dict) -> str:
    from ilcforce.store.study_read import latest_study_toml

    try:
        sessions = json.loads(str(header.get("sessions_json", "[]")))
    except ValueError:
        sessions = []
    return latest_study_toml(sessions if isinstance(sessions, list) else [], str(header.get("study_toml", "")))


def find_study_stores(results_dir: Path) -> list[Path]:
    """``results_dir/studies/*.h5`` (leftover temporary copies skipped), sorted; the paper's Monte
    Carlo (``paper-mc``) first, as the report leads with it."""
    folder = Path(results_dir) / "studies"
    if not folder.is_dir():
        return []
    found = [p for p in folder.glob("*.h5") if p.is_file() and not p.name.startswith(".")]
    return sorted(found, key=lambda p: (p.stem != "paper-mc", p.stem))


def _same(setting: dict, run: dict, method: str) -> bool:
    """Same results configuration for ``method``, the seed apart, and the same number of iterations
    (which the same-run policy ignores, as a run may be extended): a 20-iteration study must not
    stand for a 150-iteration run."""
    if any(key != "experiment.seed" for key in samerun.differences(setting, run, method)):
        return False
    iterations = [c.get("experiment", {}).get("iterations") for c in (setting, run)]
    return iterations[0] == iterations[1]


def find_study(results_dir: Path, configs: dict[str, dict]) -> StudyMatch | None:
    """The study (most seeds first) with a setting that ran ``configs`` (method -> stored config)."""
    from ilcforce.store.study import StudyStoreError, read_header

    best: StudyMatch | None = None
    for path in find_study_stores(results_dir):
        try:
            header = read_header(path)
        except (StudyStoreError, OSError):
            continue  # the study's own report says why
        methods, seeds = study_methods_and_seeds(_latest_study_toml(header))
        n_seeds = len(seeds)
        shared = [m for m in configs if methods is None or m in methods]
        if not shared or (best is not None and n_seeds <= best.n_seeds):
            continue
        for k, text in enumerate(header["settings"]["config_json"]):
            try:
                setting = json.loads(str(text))
            except ValueError:
                continue
            if all(_same(setting, configs[m], m) for m in shared):
                run_seed = configs[shared[0]].get("experiment", {}).get("seed")
                best = StudyMatch(path.stem, k, n_seeds, tuple(shared),
                                  seeds[0] if seeds else None, run_seed)
                break
    return best


def band_lines(match: StudyMatch | None, stem: str) -> list[str]:
    """The lines under single-run figure ``stem``: the matching study's bands over seeds."""
    if match is None or stem not in BAND_FIGURES:
        return []
    axis = axis_text(stem.rsplit("_", 1)[-1])  # Figs. 6 and 7: the task axis of their Delta tau
    what = {"fig3": "median and 95% bands of the same error 2-norm per iteration",
            "fig4": "median and 95% bands of the same error 2-norm per iteration",
            "fig5": "bands of the RMS and the peak over t of the position and force errors, per iteration (the "
                    "iterations drawn above shaded)"}.get(
        stem[:4], f"bands of H, the standard deviation over t of Delta tau {axis}, per iteration, in its three forms "
                  "(the iteration drawn above shaded)")
    why = "" if stem.startswith(("fig3", "fig4")) else " The study keeps per-iteration metrics, not time signals."
    seeds = f"{match.n_seeds} seeds" if match.n_seeds else "the seeds"  # a study built in code has no file
    alone = ""
    if match.first_seed is not None and why:  # Figs. 5-7 over seeds draw one seed alone; Figs. 3/4 do not
        alone = f" The dashed line is seed {match.first_seed} alone" + (
            ", this run's seed." if match.first_seed == match.run_seed else ".")
    return [f"Over {seeds}, from study [`{match.name}`](../studies/{match.name}/report.md) (setting "
            f"{match.setting}: this run's configuration, the seed apart; methods {', '.join(match.methods)}): "
            f"{what}.{why}{alone}",
            "", f"![{stem} over {seeds}]({match.figure(stem)})", ""]
