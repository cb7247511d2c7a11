"""The Q filter's cutoff against what long runs showed: the lifted check's contraction at j = 20 for every
setting of the held-out growth sets (docs/long-run/growth-fresh.md, growth-third.md, growth-fourth.md: runs of
1,000 iterations on seeds no rule was chosen on) beside that setting's three-class truth over its seeds.

The Q design of :mod:`ilcforce.theory.validation` asks every band to contract by 1% per iteration (rho <= 0.99)
and picked 400 Hz for C2-robust, which diverges at j = 758. This page shows where, in rho, the long runs turn
from bounded to unbounded, per method and robot, so that a design margin is read off evidence, with the cases
it was read from named.

    python -m ilcforce.theory.q_evidence --results results --out docs/lifted
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import pandas as pd

#: the methods with a Q-filtered memory whose cutoff is designed
FILTERED = ("c2-robust", "c3-robust", "pd-ilc")
#: the held-out sets whose runs are 1,000 iterations long (their truth is the three-class one)
SETS = ("growth-fresh", "growth-third", "growth-fourth")
#: the columns of :func:`evidence`
COLUMNS = ["set", "experiment", "setting", "method", "q_cutoff_hz", "rho", "sigma", "predicted", "seeds",
           "unbounded", "slow", "bounded", "truth", "first_divergence", "largest_growth"]


def _cases(results_dir: Path) -> tuple[dict, pd.DataFrame]:
    """The stored studies of SETS (name -> read_study result) and their cases (growth_validation)."""
    from ilcforce.report.growth_validation import load_studies, validation_cases

    found: dict[str, object] = {}
    for prefix in SETS:
        found.update(load_studies(Path(results_dir) / "studies", prefix))
    return found, (validation_cases(found) if found else pd.DataFrame())


def evidence(results_dir: Path, progress=None) -> pd.DataFrame:
    """One row per (study setting, Q-filtered method): the lifted check's spectral radius rho and largest singular
    value sigma at j = 20 (noise off) and its prediction, beside the setting's three-class truths over its seeds."""
    from ilcforce.config_load import config_from_dict
    from ilcforce.report.growth_validation import setting_config, study_settings
    from ilcforce.theory.lifted import AnalysisError, analyze

    found, cases = _cases(results_dir)
    rows = []
    for name, results in found.items():
        for k, label, _p in study_settings(results):
            data = setting_config(results, k)
            config = config_from_dict(data)
            setting = label if getattr(results, "labelled", False) and label else name
            for method in (m for m in FILTERED if m in set(results.metrics["method"].astype(str))):
                mine = cases[(cases["study"] == name) & (cases["setting"] == setting) & (cases["method"] == method)]
                if mine.empty:
                    continue
                try:
                    check = analyze(config, method)
                except AnalysisError as exc:  # e.g. the noise-free run diverges before j = 20: nothing to linearise
                    check, said = None, f"not analysed: {exc}"
                else:
                    said = "bounded" if check.bounded else "unbounded"
                if progress is not None:
                    progress(f"{name} / {setting} / {method}: {said if check is None else check.spectral_radius}")
                counts = {c: int((mine["truth_3"] == c).sum()) for c in ("unbounded", "slow", "bounded")}
                truth = ("unbounded" if counts["unbounded"] == len(mine) else
                         "bounded" if counts["bounded"] == len(mine) else "mixed")
                rows.append({"set": name.rsplit("-", 1)[0], "experiment": config.experiment.name, "setting": setting,
                             "method": method, "q_cutoff_hz": float(data.get(method, {}).get("q_cutoff", math.nan)),
                             "rho": math.nan if check is None else check.spectral_radius,
                             "sigma": math.nan if check is None else check.max_singular_value,
                             "predicted": said, "seeds": len(mine), **counts,
                             "truth": truth, "first_divergence": float(mine["diverged_at"].min()),
                             "largest_growth": float(mine["growth_3"].max())})
    return pd.DataFrame(rows, columns=COLUMNS)


def boundary(table: pd.DataFrame) -> pd.DataFrame:
    """Per (experiment, method): the largest rho among settings bounded on every seed and the smallest rho among
    settings unbounded on any seed; the two overlap where no margin in rho separates them."""
    rows = []
    for (experiment, method), group in table.groupby(["experiment", "method"], sort=True):
        group = group[group["rho"].notna()]  # a setting the check could not linearise says nothing of rho
        bounded = group[group["truth"] == "bounded"]["rho"]
        unbounded = group[group["unbounded"] > 0]["rho"]
        low, high = (float(bounded.max()) if len(bounded) else math.nan), (float(unbounded.min()) if len(unbounded)
                                                                           else math.nan)
        rows.append({"experiment": experiment, "method": method, "settings": len(group),
                     "largest rho, bounded": low, "smallest rho, unbounded": high,
                     "separated": (bool(low < high) if math.isfinite(low) and math.isfinite(high) else None)})
    return pd.DataFrame(rows)


def write_page(results_dir: Path, out_dir: Path, progress=None) -> list[Path]:
    """Write ``q-evidence.md`` and its CSVs into ``out_dir``; nothing when no held-out set is stored."""
    from ilcforce.report import table_write
    from ilcforce.report.study import studies_provenance

    start = time.perf_counter()
    table = evidence(results_dir, progress)
    if table.empty:
        return []
    found, _ = _cases(results_dir)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    edges = boundary(table)
    written = table_write.write_table(table, out_dir, "q_evidence") + table_write.write_table(
        edges, out_dir, "q_evidence_boundary")
    shown = table.assign(rho=table["rho"].map("{:.4f}".format), sigma=table["sigma"].map("{:.4f}".format),
                         largest_growth=table["largest_growth"].map("{:.3g}".format))
    lines = ["# The Q cutoff against long runs: the lifted check's contraction beside 1,000-iteration truths", "",
             f"Generated by `python -m ilcforce.theory.q_evidence --results results --out docs/lifted` from the "
             f"held-out growth sets ({studies_provenance(found)}; `make long` runs them), in "
             f"{time.perf_counter() - start:.0f} s.", "",
             "Each row is one setting of a held-out set and one Q-filtered method: rho and sigma are the spectral "
             "radius and the largest singular value of the lifted map at j = 20 with the noise off (`ilcforce "
             "analyze`), 'predicted' its verdict, and the truth is the three-class truth of each seed's 1,000 "
             "iterations (docs/long-run/growth-third.md says how it is decided): 'unbounded' or 'bounded' on every "
             "seed, else 'mixed'.", "",
             table_write.markdown_table(shown), "",
             "## Where the runs turn unbounded, in rho", "",
             "Per robot and method: the largest rho of a setting bounded on every seed, and the smallest rho of a "
             "setting unbounded on any seed. 'separated' says whether a margin in rho alone would tell them apart on "
             "these cases (learning gains change between settings too, and rho is read at j = 20 only).", "",
             table_write.markdown_table(edges), ""]
    page = out_dir / "q-evidence.md"
    page.write_text("\n".join(lines), encoding="utf-8")
    return [*written, page]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ilcforce.theory.q_evidence", description=__doc__.split("\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--out", type=Path, default=Path("docs/lifted"))
    args = parser.parse_args(argv)
    written = write_page(args.results, args.out, progress=lambda text: print(text, file=sys.stderr, flush=True))
    if not written:
        print(f"error: no held-out growth set ({', '.join(s + '-*' for s in SETS)}) in {args.results / 'studies'} "
              "(run make long)", file=sys.stderr)
        return 2
    print(f"wrote {written[-1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
