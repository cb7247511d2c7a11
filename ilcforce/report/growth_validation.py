"""The growth test checked against what long runs show: each run's truth, the test's verdict on its first
20 and 40 iterations, and the confusion matrix of the two.

Each run (setting x seed x method of a study) is one *case*. Its **truth** is what the whole run shows:
*unbounded* when it diverged, or when a settled quantity (settled H on either task axis, or a learned
memory's settled norm) grew more than TRUTH_GROWTH = 10x between j = TRUTH_FROM = 20 and its last
iteration; *bounded* otherwise (``truth_with_memories`` also counts growth of every memory, t = 0 included).
The growth test (:mod:`ilcforce.stability`) is applied to the case's first 20 and first 40
iterations alone, as a user who ran only those would see it: *flagged* (it diverged within them, or a
judged quantity grows), *not flagged* ("no growth") or *not evaluable* (inconclusive, or too few
iterations). A *miss* is an unbounded case not flagged, a *false alarm* a bounded case flagged. The page
that shows all this is :mod:`ilcforce.report.long_run`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from ilcforce import stability
from ilcforce.stability import FLAGGED, NOT_EVALUABLE, NOT_FLAGGED, diverged_at, verdict_of

#: A settled quantity grown more than this between TRUTH_FROM and the run's end makes the truth "unbounded".
TRUTH_GROWTH = 10.0
#: The iteration the truth's growth is measured from (the end of the paper's run).
TRUTH_FROM = 20
#: The horizons the growth test is judged at: the first 20 (the paper's run), 40, 100 and 200 iterations.
JUDGED_AT = (20, 40, 100, 200)
#: The horizon the test's target is stated at (0 misses, at most 10% false alarms against the truth at 1,000
#: iterations). Chosen, with the rules of ilcforce/stability.py unchanged since their freeze at c281101bd574, on the
#: growth-heldout set (seeds 560-562) against its truth at 1,000 iterations, before the fresh set
#: (FRESH_PREFIX) was drawn. There the test missed 3, 4, 1 and 0 of the unbounded cases not diverged by the
#: horizon at 20, 40, 100 and 200 iterations, and flagged 6, 6, 0 and 0 of 19 bounded ones (the frozen rules'
#: MIN_RATE = 1.01 sees slow growth only late: 10x in 1,000 iterations is 1.0024 per iteration).
STATED_HORIZON = 200
#: Settled quantities whose growth defines the truth (memory columns are added when present).
TRUTH_QUANTITIES = ("chattering_task_x_settled", "chattering_task_y_settled")
#: Every learned memory's norms (settled, whole grid, t = 0): the broader truth also counts their growth.
MEMORIES = ("memory_settled_", "memory_norm_", "memory_start_")
#: The three-class truth (``truth_3``), frozen at the commit that added it, before the third held-out set
#: (THIRD_PREFIX) was drawn. Chosen on the fresh set (FRESH_PREFIX), whose nine false alarms at the stated horizon
#: were C2-robust runs whose learned memory at t = 0 drifts x13 to x3,000 over 1,000 iterations while nothing
#: settled grows: the frozen truth, on settled quantities alone, called them bounded. This one counts every
#: quantity the test judges (settled H on every task axis, every learned memory's norm: settled, whole grid and
#: t = 0) but a memory the law caps (bounded by construction, :func:`ilcforce.stability.capped`) and a memory of
#: round-off size at the run's end (below :data:`ilcforce.stability.ROUNDOFF` of its block's settled RMS, the
#: test's own floor). Its largest growth G from j = TRUTH_FROM to the run's end decides: "unbounded" when the run
#: diverged or G > SLOW_HIGH, "bounded" when G <= SLOW_LOW, and "slow" in between: 5-20x over 980 iterations is
#: 1.0016-1.0031 per iteration, and 1,000 iterations cannot tell such a drift towards divergence from one that
#: levels off (the fresh set's C3-robust Theta_hat at t = 0 grew x14-15). A slow case is neither a miss nor a
#: false alarm; the pages count it apart, flagged or not.
SLOW_LOW = 5.0
SLOW_HIGH = 20.0
#: The classes of the three-class truth, in the order the pages show them.
TRUTH_CLASSES = ("unbounded", "slow", "bounded")


def largest_growth(frame: pd.DataFrame, columns: list[str]) -> tuple[float, str]:
    """The largest factor by which one of ``columns`` grew from j = TRUTH_FROM to the run's last complete
    iteration, and a text naming it (NaN, "" when none can be compared)."""
    complete = frame[frame["status"] == "complete"]
    start = complete[complete["iteration"] == TRUTH_FROM]
    worst, what = math.nan, ""
    if len(start) and len(complete):
        end = complete.iloc[-1]
        for column in columns:
            a, b = float(start.iloc[0][column]), float(end[column])
            if a > 0 and math.isfinite(a) and math.isfinite(b):
                factor = b / a
                if not math.isfinite(worst) or factor > worst:
                    worst, what = factor, f"{stability.short_name(column)} x{factor:.3g} from j = {TRUTH_FROM} to " \
                                          f"{int(end['iteration'])}"
    return worst, what


def truth_of(frame: pd.DataFrame) -> tuple[str, str, float]:
    """("unbounded" / "bounded", the reason, the largest settled growth factor) of one run (one seed, one
    method, sorted by iteration) from all its iterations."""
    diverged = diverged_at(frame)
    columns = [c for c in TRUTH_QUANTITIES if c in frame] + sorted(c for c in frame if c.startswith("memory_settled_"))
    worst, what = largest_growth(frame, columns)
    if math.isfinite(diverged):
        return "unbounded", f"diverged at j = {int(diverged)}", worst
    if math.isfinite(worst) and worst > TRUTH_GROWTH:
        return "unbounded", what, worst
    return "bounded", what or "no settled quantity to compare", worst


def truth_3_of(frame: pd.DataFrame, method: str, config: dict | None = None) -> tuple[str, str, float]:
    """The three-class truth of one run (sorted by iteration; see SLOW_LOW): ("unbounded" / "slow" /
    "bounded", the reason, the largest growth factor G of the quantities it counts)."""
    diverged = diverged_at(frame)
    complete = frame[frame["status"] == "complete"]
    caps = stability.capped(config, method)
    values = {c: complete[c].to_numpy(dtype=float) for c in complete if c.startswith(MEMORIES)}
    memories = [c for c in sorted(values) if not any(c.endswith(f"_{name}") for name in caps)
                and len(values[c]) and not stability.negligible(c, values[c], values)]
    columns = [c for c in stability.WATCHED if c in frame] + memories
    worst, what = largest_growth(frame, columns)
    if math.isfinite(diverged):
        return "unbounded", f"diverged at j = {int(diverged)}", worst
    if math.isfinite(worst) and worst > SLOW_HIGH:
        return "unbounded", what, worst
    if math.isfinite(worst) and worst > SLOW_LOW:
        return "slow", what, worst
    return "bounded", what or "no quantity to compare", worst


def study_settings(results):
    from ilcforce.report.study import setting_perturbation

    for setting in results.settings.itertuples(index=False):
        yield int(setting.setting), str(setting.label or ""), setting_perturbation(setting.config_json)


def setting_config(results, k: int) -> dict:
    return json.loads(str(results.settings.set_index("setting").loc[k, "config_json"]))


def validation_cases(studies: dict[str, object], midpoint: bool = True) -> pd.DataFrame:
    """One row per run of the given study results (name -> ``read_study`` result): the truth from the
    whole run and the test's verdict at each horizon of JUDGED_AT (``midpoint=False``: the test as frozen at
    c281101bd574, before the midpoint reading)."""
    rows = []
    for name, results in studies.items():
        for k, label, p in study_settings(results):
            metrics = results.setting_metrics(k)
            config = setting_config(results, k)
            for (seed, method), frame in metrics.groupby(["seed", "method"], sort=True):
                frame = frame.sort_values("iteration")
                truth, reason, factor = truth_of(frame)
                memory, memory_text = largest_growth(frame, sorted(c for c in frame if c.startswith(MEMORIES)))
                setting = label if getattr(results, "labelled", False) and label else name
                row = {"study": name, "setting": setting, "seed": int(seed), "method": str(method),
                       "iterations_run": int(frame["iteration"].max()) + 1, "diverged_at": diverged_at(frame),
                       "truth": truth, "truth_reason": reason, "settled_growth": factor,
                       "memory_growth": memory_text or "-",
                       "truth_with_memories": ("unbounded" if truth == "unbounded" or memory > TRUTH_GROWTH
                                               else "bounded")}
                row["truth_3"], row["truth_reason_3"], row["growth_3"] = truth_3_of(frame, str(method), config)
                for horizon in JUDGED_AT:
                    row[f"verdict_{horizon}"], row[f"test_{horizon}"] = verdict_of(frame, str(method), horizon, p, config,
                                                                                midpoint)
                rows.append(row)
    return pd.DataFrame(rows)


#: Studies drawn after the test's rules were frozen (``experiments/long/growth-heldout-*.toml``): the out-of-sample set.
HELDOUT_PREFIX = "growth-heldout"
#: The same cases rerun to 1,000 iterations (``experiments/long/heldout-1000-*.toml``; ``heldout-1000-X`` reruns
#: cases of ``growth-heldout-X`` with nothing but the run's length changed): their truth at that horizon.
LONGER_PREFIX = "heldout-1000"
#: The rule changes, and the cases each was made on (the in-sample set: the growth-validation studies).
RULE_HISTORY = (
    ("the error 2-norms shown, no longer judged", "after PD-ILC's bounded runs were flagged on them in the "
     "growth-validation studies (seeds 71, 72)"),
    ("the saturating rule (increments shrinking geometrically are growth towards a limit)", "on the same "
     "growth-validation studies (C3-robust's alpha_hat and the Q-filtered memories filling as they learn)"),
    ("a memory of round-off size (below 1e-6 of its block's settled RMS) not judged", "on C2-robust at "
     "q_cutoff = 1500 Hz, seed 141, a case outside both sets"),
    (f"the target stated at {STATED_HORIZON} iterations (the rules unchanged)", "on the growth-heldout set, seeds "
     "560-562, against its truth at 1,000 iterations; the fresh set was drawn after it"),
    ("the three-class truth (every judged quantity counts; growth of 5-20x is \"slow\", neither right nor wrong; "
     "the test's rules and horizon unchanged)", "on the fresh set, seeds 600-602, whose false alarms were C2-robust "
     "runs with a drifting t = 0 memory; the third set was drawn after it"),
    ("the midpoint reading (a run of 100 iterations or more is also read over the later half of its first "
     "half; runs shorter than 100 read as before)", "on the third set, seeds 700-702, where the robust laws' t = 0 "
     "memory grew fast over j = 50-100 and slowly over j = 100-199; the fourth set was drawn after it"),
)
#: Studies drawn after the horizon was frozen (``experiments/long/growth-fresh-*.toml``, seeds 600-602, runs of
#: 1,000 iterations): the set the stated horizon is validated on.
FRESH_PREFIX = "growth-fresh"
#: Studies drawn after the three-class truth was frozen (``experiments/long/growth-third-*.toml``, runs of 1,000
#: iterations): the set the test is validated on against that truth.
THIRD_PREFIX = "growth-third"
#: Studies drawn after the midpoint reading was frozen (``experiments/long/growth-fourth-*.toml``, runs of 1,000
#: iterations): the set the test with that reading is validated on.
FOURTH_PREFIX = "growth-fourth"


def rates(cases: pd.DataFrame, horizon: int, truth: str = "truth") -> pd.DataFrame:
    """Misses, false alarms and "not evaluable" at ``horizon`` as counts with 95% Wilson intervals. A miss is an
    unbounded case that had not diverged by ``horizon`` and was not flagged; a false alarm a bounded case
    flagged; "not evaluable" is counted over every case (it is neither right nor wrong, so it is its own row)."""
    from ilcforce.stats import frequency_interval

    unbounded = cases[(cases[truth] == "unbounded") & ~(cases["diverged_at"] < horizon)]
    bounded = cases[cases[truth] == "bounded"]
    slow = cases[cases[truth] == "slow"]  # the three-class truth's middle class
    verdict = f"verdict_{horizon}"
    rows = []
    for what, hits, among, of in (
            ("misses", int((unbounded[verdict] != FLAGGED).sum()), len(unbounded),
             f"unbounded cases not diverged by j = {horizon}"),
            ("  of which not evaluable", int((unbounded[verdict] == NOT_EVALUABLE).sum()), len(unbounded),
             f"unbounded cases not diverged by j = {horizon}"),
            ("false alarms", int((bounded[verdict] == FLAGGED).sum()), len(bounded), "bounded cases"),
            *([("slow cases flagged (neither right nor wrong)", int((slow[verdict] == FLAGGED).sum()), len(slow),
                "slow cases")] if len(slow) else []),
            ("not evaluable", int((cases[verdict] == NOT_EVALUABLE).sum()), len(cases), "cases")):
        share = frequency_interval(hits, among)
        rows.append({"horizon": horizon, "what": what, "count": hits, "of": among, "among": of,
                     "rate": share.estimate, "rate_low": share.low, "rate_high": share.high})
    return pd.DataFrame(rows)


def confusion(cases: pd.DataFrame, horizon: int, truth: str = "truth") -> pd.DataFrame:
    """Counts of cases per truth (rows: unbounded, slow where there are any, bounded) and verdict at ``horizon``
    (columns); ``truth`` names the column of the truth ("truth", "truth_with_memories": every memory's growth
    counts, or "truth_3": the three-class truth)."""
    classes = [c for c in TRUTH_CLASSES if c != "slow" or (cases[truth] == "slow").any()]
    table = pd.crosstab(cases[truth], cases[f"verdict_{horizon}"]).reindex(
        index=classes, columns=[FLAGGED, NOT_FLAGGED, NOT_EVALUABLE], fill_value=0)
    table.index.name, table.columns.name = "truth", f"test on the first {horizon} iterations"
    return table


def confusion_text(cases: pd.DataFrame, horizon: int, truth: str = "truth", *, names: bool = True) -> str:
    """"2 of 31 unbounded cases missed (...); 1 of 40 bounded cases falsely flagged (2.5%)"."""
    unbounded = cases[cases[truth] == "unbounded"]
    bounded = cases[cases[truth] == "bounded"]
    verdict = f"verdict_{horizon}"
    # a case that diverges within the horizon is flagged by construction: the goal is about the later ones
    later = unbounded[~(unbounded["diverged_at"] < horizon)]
    missed = later[later[verdict] != FLAGGED]
    false = bounded[bounded[verdict] == FLAGGED]
    unsure = cases[cases[verdict] == NOT_EVALUABLE]
    share = f" ({100 * len(false) / len(bounded):.0f}%)" if len(bounded) else ""
    slow = cases[cases[truth] == "slow"]
    slow_text = (f"; {len(slow)} slow ({int((slow[verdict] == FLAGGED).sum())} flagged, neither right nor wrong)"
                 if len(slow) else "")
    reason = "truth_reason" + truth[len("truth"):]  # truth_1000's reasons are truth_reason_1000
    reason = reason if reason in cases else "truth_reason"
    # a case is named by method, setting and seed, and by its study too where two studies share that name
    named = [f"{r.method}, {r.setting}, seed {r.seed}" for r in cases.itertuples()]
    shared = {name for name in named if named.count(name) > 1}

    def name(r) -> str:
        text = f"{r.method}, {r.setting}, seed {r.seed}"
        return f"{text} ({r.study})" if text in shared and "study" in cases else text

    missing = "; ".join(f"{name(r)}: {getattr(r, reason)}" for r in missed.itertuples())
    alarms = "; ".join(name(r) for r in false.itertuples()) if names else ""
    return (f"{len(missed)} of the {len(later)} unbounded cases that had not diverged by j = {horizon} missed"
            + (f" ({missing})" if missing else "") + f"; {len(false)} of {len(bounded)} bounded cases flagged{share}"
            + (f" ({alarms})" if alarms else "") + slow_text + f"; {len(unsure)} not evaluable")



def load_studies(study_dir: Path, prefix: str) -> dict[str, object]:
    """The readable study stores ``study_dir/<prefix>*.h5`` by name (a damaged one is left out)."""
    from ilcforce.study import StudyStoreError, read_study

    found: dict[str, object] = {}
    for path in sorted(study_dir.glob(f"{prefix}*.h5")) if study_dir.is_dir() else []:
        try:
            found[path.stem] = read_study(path)
        except (StudyStoreError, OSError, KeyError, ValueError, TypeError):
            continue
    return found


def with_longer_truth(cases: pd.DataFrame, longer: pd.DataFrame) -> pd.DataFrame:
    """``cases`` with ``truth_1000``, ``truth_reason_1000`` and ``iterations_run_1000``: the truth of the same
    case rerun to 1,000 iterations where ``longer`` (the ``heldout-1000-*`` studies' cases) has it, else the
    300-iteration truth when that is "unbounded" (a diverged run stays diverged; a run that grew tenfold by
    j = 300 is not rerun), else missing (a bounded case not rerun has no longer truth). ``verdicts_agree``: the
    rerun's verdicts on its first iterations are the original's (the same run, only longer)."""
    longer = longer.copy()
    original = longer["study"].str.replace(LONGER_PREFIX, HELDOUT_PREFIX, n=1, regex=False)
    longer["setting"] = [o if setting == study else setting
                         for setting, study, o in zip(longer["setting"], longer["study"], original)]
    longer["study"] = original
    key = ["study", "setting", "seed", "method"]
    merged = cases.merge(longer[key + ["truth", "truth_reason", "iterations_run"]
                                + [f"verdict_{h}" for h in JUDGED_AT]].rename(columns={
        "truth": "truth_1000", "truth_reason": "truth_reason_1000", "iterations_run": "iterations_run_1000",
        **{f"verdict_{h}": f"rerun_verdict_{h}" for h in JUDGED_AT}}), on=key, how="left")
    kept = merged["truth_1000"].isna() & (merged["truth"] == "unbounded")
    merged.loc[kept, "truth_1000"] = "unbounded"
    merged.loc[kept, "truth_reason_1000"] = "unbounded within 300 iterations (not rerun)"
    rerun = merged["iterations_run_1000"].notna()
    merged["verdicts_agree"] = ~rerun | np.logical_and.reduce(
        [merged[f"verdict_{h}"] == merged[f"rerun_verdict_{h}"] for h in JUDGED_AT])
    return merged.drop(columns=[f"rerun_verdict_{h}" for h in JUDGED_AT])


#: The growth test's target at STATED_HORIZON: no miss, and at most this share of the bounded cases flagged.
TARGET_FALSE_ALARMS = 0.10


def target_text(cases: pd.DataFrame, horizon: int = STATED_HORIZON, truth: str = "truth") -> str:
    """"met: 0 of 12 missed [0%, 24%], 1 of 30 false alarms 3% [1%, 17%]" at ``horizon``: the target (no miss, at
    most TARGET_FALSE_ALARMS of the bounded cases flagged) on the point counts, with their 95% Wilson intervals."""
    shares = rates(cases, horizon, truth).set_index("what")
    miss, alarm = shares.loc["misses"], shares.loc["false alarms"]
    met = int(miss["count"]) == 0 and int(alarm["of"]) > 0 and alarm["rate"] <= TARGET_FALSE_ALARMS
    return (f"{'met' if met else 'not met'}: {int(miss['count'])} of {int(miss['of'])} unbounded cases not diverged by "
            f"j = {horizon} missed ({_share(miss)}), {int(alarm['count'])} of {int(alarm['of'])} bounded cases flagged "
            f"({_share(alarm)}; the target allows {TARGET_FALSE_ALARMS:.0%})")


def _share(row) -> str:
    return f"{row['rate']:.0%} [{row['rate_low']:.0%}, {row['rate_high']:.0%}]" if row["of"] else "none to count"
