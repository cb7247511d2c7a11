"""The cross-check's page (docs/crosscheck.md, ``make crosscheck``): the methods with n-axis laws on the 2R arm and
the spatial arm, ilcforce's plant beside MuJoCo's, for a short horizon, each MuJoCo contact variant in its own
table; every number on the page comes from this run.

``python -m ilcforce.crosscheck.page --experiments A.toml,B.toml --out docs/crosscheck.md`` (options: ``--iters``,
``--seed``, ``--methods``); ``make crosscheck`` names the 2R arm's and the spatial arm's experiments.
"""

from __future__ import annotations

import datetime
import math
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from ilcforce.crosscheck.mujoco_plant import ContactSettings
from ilcforce.crosscheck.mujoco_run import (CROSSCHECK_METHODS, CrossRow, _OneLineParser, crosscheck_config,
                                            mujoco_iterations, own_iterations)
from ilcforce.records import STATUS_COMPLETE, task_axes

#: MuJoCo's contact variants: (label, settings). The first is the wall ilcforce models (an undamped spring K_e);
#: the second adds MuJoCo's default damping ratio (its solref's 1: critically damped); the third a larger
#: impedance, whose added mass d / (1 - d) of the contact's effective mass is 10x the first's
VARIANTS = (
    ("spring K_e, zeta = 0, d = 1e-4", ContactSettings(damping_ratio=0.0, impedance=1e-4)),
    ("spring K_e, zeta = 1 (MuJoCo's default damping ratio), d = 1e-4", ContactSettings(damping_ratio=1.0, impedance=1e-4)),
    ("spring K_e, zeta = 0, d = 1e-3", ContactSettings(damping_ratio=0.0, impedance=1e-3)),
)
#: the verdict's rule on one seed: both runs finish every iteration, and at the last iteration e_P, e_F and every
#: settled H are within AGREEMENT_FACTOR of each other; or both diverge, in iterations at most
#: DIVERGENCE_SLACK apart
AGREEMENT_FACTOR = 2.0
DIVERGENCE_SLACK = 2


@dataclass
class Cell:
    experiment: str
    method: str
    axes: tuple[str, ...]
    ours: list[CrossRow]
    theirs: dict[str, list[CrossRow]]  # variant label -> MuJoCo's rows
    contact: dict[str, str]  # variant label -> MuJoCo's parameters, one line per true plant


def _last(rows: list[CrossRow]) -> CrossRow | None:
    return rows[-1] if rows else None


def _outcome(rows: list[CrossRow], iterations: int) -> str:
    last = _last(rows)
    if last is None:
        return "not run"
    if last.status == STATUS_COMPLETE and len(rows) == iterations:
        return f"{iterations} complete"
    return f"diverged in j = {last.iteration} at t = {last.diverged_time:.3f} s"


def _ratio_ok(a: float, b: float) -> bool:
    if not (math.isfinite(a) and math.isfinite(b)):
        return False
    if a == b:
        return True
    return min(a, b) > 0 and max(a, b) / min(a, b) <= AGREEMENT_FACTOR


def verdict(ours: list[CrossRow], theirs: list[CrossRow], iterations: int) -> str:
    """'agrees', or what differs, by :data:`AGREEMENT_FACTOR`'s rule."""
    done_o = len(ours) == iterations and ours[-1].status == STATUS_COMPLETE
    done_m = len(theirs) == iterations and theirs[-1].status == STATUS_COMPLETE
    if done_o != done_m:
        return "differs: " + ("only MuJoCo's diverged" if done_o else "only ilcforce's diverged")
    if not done_o:
        j_o, j_m = ours[-1].iteration, theirs[-1].iteration
        if abs(j_o - j_m) <= DIVERGENCE_SLACK:
            return f"agrees (both diverged: j = {j_o} / {j_m})"
        return f"differs: diverged in j = {j_o} / {j_m}"
    o, m = ours[-1], theirs[-1]
    pairs = [("e_P", o.position_error_rms, m.position_error_rms), ("e_F", o.force_error_rms, m.force_error_rms),
             *((f"H[{i}]", a, b) for i, (a, b) in enumerate(zip(o.settled_h, m.settled_h)))]
    off = [name for name, a, b in pairs if not _ratio_ok(a, b)]
    return "agrees" if not off else "differs: " + ", ".join(off)


def _g(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.3g}"


def _pair(o: CrossRow | None, m: CrossRow | None, get) -> str:
    a = _g(get(o)) if o is not None and o.status == STATUS_COMPLETE else "-"
    b = _g(get(m)) if m is not None and m.status == STATUS_COMPLETE else "-"
    return f"{a} / {b}"


def run_cells(iterations: int, seed: int, experiments, variants=VARIANTS, say=print, methods=CROSSCHECK_METHODS) -> tuple[list[Cell], dict[str, list[float]]]:
    """Every (experiment, method): ilcforce's run once, MuJoCo's per variant; and MuJoCo's seconds per
    iteration per variant (the first iteration of each cell left out: it builds the model and may compile)."""
    from ilcforce.config_load import load_config

    cells, seconds = [], {label: [] for label, _ in variants}
    for name in experiments:
        config = crosscheck_config(load_config(name, {"experiment.seed": seed}), iterations)
        axes = task_axes(config.dimension)
        for method in methods:
            ours = [CrossRow.of(m, axes) for m in own_iterations(config, method)]
            cell = Cell(config.experiment.name, method, axes, ours, {}, {})
            for label, contact in variants:
                arms: dict = {}
                rows = []
                for _record, metrics, spent in mujoco_iterations(config, method, contact, arms):
                    rows.append(CrossRow.of(metrics, axes, spent))
                seconds[label] += [r.seconds for r in rows[1:]]
                cell.theirs[label] = rows
                from ilcforce.crosscheck.mujoco_plant import describe

                cell.contact[label] = "; ".join(dict.fromkeys(describe(arm, contact) for arm in arms.values()))
                say(f"{name} / {method} / {label}: ours {_outcome(ours, iterations)}, MuJoCo "
                    f"{_outcome(rows, iterations)}, {verdict(ours, rows, iterations)}")
            cells.append(cell)
    return cells, seconds


def _model_files(cells: list[Cell]) -> str:
    """Each experiment's model file, as its plant names it (experiment: file)."""
    from pathlib import PurePath

    from ilcforce.config_load import load_config

    out = []
    for name in dict.fromkeys(c.experiment for c in cells):
        path = getattr(load_config(name).plant.nominal(), "path", "")
        out.append(f"{name}: experiments/models/{PurePath(path).name}" if path else name)
    return "; ".join(out)


def _feedback_gains(cells: list[Cell], contact: ContactSettings) -> str:
    """Per robot and method, the acceleration feedback k lambda_F2 c (kg) a damped wall puts in the force loop,
    beside the contact's effective mass 1 / A (kg) at the nominal plant's start."""
    from ilcforce.config_load import load_config
    from ilcforce.crosscheck.mujoco_plant import build_arm
    from ilcforce.crosscheck.mujoco_run import initial_state
    from ilcforce.simulate import force_axis

    parts = []
    for name in dict.fromkeys(c.experiment for c in cells):
        config = load_config(name)
        fa = force_axis(config.surface.selection)
        nominal = config.plant.nominal()
        arm = build_arm(nominal, config.wall, fa, contact, config.simulation.sample_time,
                        initial_state(config, nominal)[0])
        A, c = arm.contact["A"], arm.contact["damping"]
        gains = ", ".join(f"{cell.method} {getattr(config.gains[cell.method], 'k')[fa] * config.surface.lambda_f2[fa] * c:.3g}"
                          for cell in cells if cell.experiment == name and hasattr(config.gains[cell.method], "k"))
        parts.append(f"{name}: 1 / A = {1 / A:.3g} kg, k lambda_F2 c = {gains} kg")
    return "; ".join(parts)


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, timeout=10,
                              check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def render(cells: list[Cell], seconds: dict[str, list[float]], iterations: int, seed: int, command: str,
           wall_time: float, variants=VARIANTS, methods=CROSSCHECK_METHODS, extra: dict | None = None) -> str:
    """The page's Markdown."""
    import mujoco

    lines = [
        "# The contact model cross-checked: MuJoCo as the plant",
        "",
        f"Written by `{command}` at commit `{_commit()}` on "
        f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, MuJoCo {mujoco.__version__}; the run "
        f"took {wall_time / 60:.1f} minutes on this machine. Every number below comes from that run.",
        "",
        "ilcforce simulates its robots with its own rigid-body dynamics (RK4 with the torque held over each control "
        "sample) and a linear spring wall, F = K_e max(0, w (y - y_e)) (docs/model.md#wall). This page runs the same "
        "controllers on the same task with MuJoCo doing the physics: the arm as MuJoCo reads it from its model file "
        f"({_model_files(cells)}), the wall "
        "a MuJoCo plane, the force MuJoCo's own soft contact (module `ilcforce.crosscheck`). The sensor noise and the "
        "disturbance are ilcforce's draws for the same seed and iteration, the reference, metrics and learning "
        "updates ilcforce's; each control sample reads MuJoCo's state and contact force, builds the measurement "
        "vector from the nominal model as ilcforce's loop does, and calls the method's compiled n-axis law.",
        "",
        f"Horizon: {iterations} iterations, seed {seed}, methods {', '.join(methods)} (those with n-axis "
        "laws). Both sides run the *filtered* acceleration scheme (docs/model.md#acceleration): the implicit scheme, "
        "ilcforce's default, solves the algebraic loop through ilcforce's own plant, which a MuJoCo run does not "
        "have. So the \"ours\" numbers here are ilcforce's plant with the filtered scheme, not the stored runs. One "
        "seed is a cross-check, not a study: a \"differs\" below says where to look, not that a verdict changes.",
        "",
        "## Contact",
        "",
        "MuJoCo's contact is a soft constraint. With a flat impedance d (solimp = [d, d, 0.001, 0.5, 2]) and solref "
        "given directly as stiffness s and damping b (its negative form), the normal force in contact is "
        "f = (s r + b v) / ((1 - d) A) + d / (1 - d) (1 / A) a1, with r the penetration, v its rate, A MuJoCo's "
        "constant estimate of the contact's inverse effective mass and a1 the contact point's normal acceleration. "
        "The cross-check sets s = K_e (1 - d) A and b = c (1 - d) A, reading A from a contact MuJoCo makes for each "
        "true plant, so the spring is K_e = 1000 N/m exactly (tests/test_crosscheck.py holds it to 1e-8 in "
        "equilibrium) and the damper is c = 2 zeta sqrt(K_e / A). What remains of MuJoCo's formulation is the "
        "added mass d / (1 - d) / A: an inertial force on the contact, which the measured force includes. The "
        "wall plane sits behind a 1 mm sphere at the tool by the sphere's radius, so MuJoCo's penetration is "
        "ilcforce's. The contact is frictionless (condim 1), as ilcforce's wall. The integrator is MuJoCo's RK4 at "
        "a timestep equal to the control sample time Ts = 0.1 ms; with contact off, MuJoCo's free motion equals "
        "ilcforce's plant to within RK4's own error (tests/test_crosscheck.py).",
        "",
        "MuJoCo's parameters, per variant and robot (a perturbed true plant has its own A, so its own solref):",
        "",
    ]
    for label, _contact in variants:
        lines.append(f"- {label}:")
        for name in dict.fromkeys(c.experiment for c in cells):
            text = next((c.contact.get(label, "") for c in cells if c.experiment == name and c.contact.get(label)), "")
            lines.append(f"  - {name}: {text}")
    lines += ["", "## Results", "",
              "Each cell gives ilcforce's value / MuJoCo's, at the last iteration both runs completed "
              "(\"-\" where a run diverged before it). e_P and e_F are RMS over the 2 s iteration (m, N); H is the "
              "settled chattering (N, t >= 20 ms; docs/model.md#metrics) per task axis. The verdict's rule: both runs "
              f"complete all {iterations} iterations and at the last iteration e_P, e_F and every settled H are "
              f"within a factor {AGREEMENT_FACTOR:g} of each other; or both diverge, in iterations at most "
              f"{DIVERGENCE_SLACK} apart.", ""]
    for label, _contact in variants:
        secs = seconds.get(label, [])
        speed = (f"MuJoCo took a median {statistics.median(secs):.2f} s per iteration ({len(secs)} iterations, each "
                 "cell's first left out)" if secs else "no iteration past each cell's first")
        lines += [f"### MuJoCo wall: {label}", "", f"{speed}.", ""]
        lines += ["| robot | method | ilcforce | MuJoCo | e_P at j = 0 | e_P last | e_F at j = 0 | e_F last | settled H "
                  "last (per axis) | verdict |", "|---|---|---|---|---|---|---|---|---|---|"]
        for c in cells:
            theirs = c.theirs.get(label, [])
            last_both = min(len(c.ours), len(theirs))
            o_last = next((c.ours[j] for j in range(last_both - 1, -1, -1) if c.ours[j].status == STATUS_COMPLETE
                           and theirs[j].status == STATUS_COMPLETE), None)
            m_last = theirs[o_last.iteration] if o_last is not None else None
            o0 = c.ours[0] if c.ours else None
            m0 = theirs[0] if theirs else None
            h = ", ".join(f"{a}: {_pair(o_last, m_last, lambda r, i=i: r.settled_h[i])}" for i, a in enumerate(c.axes))
            last_j = f" (j = {o_last.iteration})" if o_last is not None and o_last.iteration != iterations - 1 else ""
            lines.append(
                f"| {c.experiment} | {c.method} | {_outcome(c.ours, iterations)} | {_outcome(theirs, iterations)} | "
                f"{_pair(o0, m0, lambda r: r.position_error_rms)} | "
                f"{_pair(o_last, m_last, lambda r: r.position_error_rms)}{last_j} | "
                f"{_pair(o0, m0, lambda r: r.force_error_rms)} | {_pair(o_last, m_last, lambda r: r.force_error_rms)} | "
                f"{h} | {verdict(c.ours, theirs, iterations)} |")
        lines.append("")
    if extra:
        lines += _over_seeds(cells, extra, seed, iterations, variants[0][0])
    lines += _explanations(cells, variants, iterations)
    return "\n".join(lines) + "\n"


def _over_seeds(cells: list[Cell], extra: dict, seed: int, iterations: int, label: str) -> list[str]:
    """The first variant's verdict and last-iteration e_F (ilcforce / MuJoCo) on every seed run."""
    seeds = [seed, *extra]
    by_seed = {seed: {(c.experiment, c.method): c for c in cells}}
    by_seed.update({s: {(c.experiment, c.method): c for c in rows} for s, rows in extra.items()})
    lines = [f"### Over seeds: {label}", "",
             f"The same {iterations} iterations on seeds {', '.join(map(str, seeds))} (the first variant only): the "
             "verdict, and e_F (N, RMS) at the last iteration both runs completed, ilcforce's / MuJoCo's.", "",
             "| robot | method | " + " | ".join(f"seed {s}" for s in seeds) + " |",
             "|---|---|" + "---|" * len(seeds)]
    for c in cells:
        row = []
        for s in seeds:
            other = by_seed[s].get((c.experiment, c.method))
            if other is None:
                row.append("not run")
                continue
            theirs = other.theirs.get(label, [])
            both = [j for j in range(min(len(other.ours), len(theirs)))
                    if other.ours[j].status == STATUS_COMPLETE and theirs[j].status == STATUS_COMPLETE]
            e_f = (f"{_g(other.ours[both[-1]].force_error_rms)} / {_g(theirs[both[-1]].force_error_rms)}"
                   if both else "-")
            row.append(f"{verdict(other.ours, theirs, iterations)}; e_F {e_f}")
        lines.append(f"| {c.experiment} | {c.method} | " + " | ".join(row) + " |")
    total = sum(1 for s in seeds for c in by_seed[s].values()
                if verdict(c.ours, c.theirs.get(label, []), iterations).startswith("agrees"))
    lines += ["", f"{total} of {len(cells) * len(seeds)} runs agree by the rule above.", ""]
    return lines


def _explanations(cells: list[Cell], variants, iterations: int) -> list[str]:
    """Why the two plants' numbers differ, mechanism by mechanism; the counts come from the tables."""
    def count(label, rule):
        return sum(1 for c in cells if rule(verdict(c.ours, c.theirs.get(label, []), iterations)))

    first = variants[0][0]
    base = variants[0][1]
    lines = ["## Why the numbers differ", "",
             f"- With the wall ilcforce models ({first}), {count(first, lambda v: v.startswith('agrees'))} of "
             f"{len(cells)} method-robot pairs agree by the rule above. What still differs between the plants: "
             f"MuJoCo's contact force carries the added-mass term ({base.impedance:g} of the effective mass times the contact "
             "point's acceleration, which the torque's sample-to-sample chatter makes large); the force is read "
             "from MuJoCo's forward dynamics at the sample with the previous sample's torque still held; the "
             "disturbance's joint force is held over each step at the step's middle instead of evaluated at RK4's "
             "stages; and MuJoCo integrates the true plant with its own algorithms (its composite-rigid-body mass "
             "matrix and recursive Newton-Euler bias forces). The settled H is the quantity most sensitive to "
             "these: it measures the torque's chatter, which feeds through the measured force."]
    for label, contact in variants[1:]:
        why = []
        if contact.damping_ratio != base.damping_ratio:
            why.append(f"a damper (zeta = {contact.damping_ratio:g}; c = 2 zeta sqrt(K_e / A), in N s/m in the "
                       "parameters above) adds c v to the force the sensor measures. A candidate mechanism, which this "
                       "run does not isolate: the force rate every law feeds back (lambda_F2 dF/dt in sigma, eq. 8) "
                       "then carries c times the tool's normal acceleration, an acceleration feedback of k lambda_F2 c "
                       "kg along the force axis, many times the contact's effective mass 1 / A "
                       f"({_feedback_gains(cells, contact)}); the table shows that a large ratio alone does not "
                       "decide divergence")
        if contact.impedance != base.impedance:
            why.append(f"the impedance d = {contact.impedance:g} makes the added mass "
                       f"{contact.impedance / base.impedance:g} times the first variant's, an inertial force the "
                       "sensor measures with the force")
        lines.append(f"- {label}: {count(label, lambda v: v.startswith('agrees'))} of {len(cells)} pairs agree; "
                     f"{count(label, lambda v: 'only MuJoCo' in v)} diverge on MuJoCo's plant only. Here "
                     f"{'; '.join(why) or 'nothing but the settings above differs'}. Either is fed back through the "
                     "force axis's high gain, so a force loop that holds on a pure spring need not hold on a wall "
                     "that is not one.")
    lines += ["", "Reproduce: `make crosscheck` (or the command at the top of this page); one method's per-iteration "
              "table: `python -m ilcforce.crosscheck.mujoco_run experiments/arm3.toml -m c3 -n 20` (options "
              "`--damping-ratio`, `--impedance`, `--integrator`, `--seed`)."]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = _OneLineParser.make("python -m ilcforce.crosscheck.page", __doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/crosscheck.md"))
    parser.add_argument("--iters", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", default=",".join(CROSSCHECK_METHODS))
    parser.add_argument("--experiments", required=True, help="comma-separated experiment files")
    parser.add_argument("--save", type=Path, default=None, help="also keep the run's rows here (pickle)")
    parser.add_argument("--load", type=Path, default=None, help="render the rows a --save kept, without running them again")
    parser.add_argument("--extra-seeds", default="", help="comma-separated seeds run with the first contact variant only")
    args = parser.parse_args(argv)
    methods = tuple(m for m in args.methods.split(",") if m)
    experiments = tuple(e for e in args.experiments.split(",") if e)
    try:
        extra_seeds = tuple(int(v) for v in args.extra_seeds.split(",") if v.strip())
    except ValueError:
        print(f"error: --extra-seeds must be comma-separated integers, got {args.extra_seeds!r}", file=sys.stderr)
        return 2
    if args.iters < 1:
        print(f"error: --iters must be >= 1, got {args.iters}", file=sys.stderr)
        return 2
    command = f"python -m ilcforce.crosscheck.page --out {args.out} --iters {args.iters} --seed {args.seed}"
    if methods != CROSSCHECK_METHODS:
        command += f" --methods {','.join(methods)}"
    command = command.replace(" --out", f" --experiments {','.join(experiments)} --out", 1)
    if extra_seeds:
        command += f" --extra-seeds {','.join(map(str, extra_seeds))}"
    import pickle

    started = time.perf_counter()
    try:
        say = lambda text: print(text, file=sys.stderr, flush=True)  # noqa: E731
        if args.load is not None:  # the rows kept, and the extra seeds they do not have yet
            kept = pickle.loads(args.load.read_bytes())
            cells, seconds, wall_time = kept[:3]
            extra = kept[3] if len(kept) > 3 else {}
        else:
            cells, seconds = run_cells(args.iters, args.seed, experiments, say=say, methods=methods)
            wall_time, extra = time.perf_counter() - started, {}
        for seed in extra_seeds:
            if seed not in extra:
                begun = time.perf_counter()
                extra[seed] = run_cells(args.iters, seed, experiments, VARIANTS[:1], say=say, methods=methods)[0]
                wall_time += time.perf_counter() - begun
        if args.save is not None:
            args.save.parent.mkdir(parents=True, exist_ok=True)
            args.save.write_bytes(pickle.dumps((cells, seconds, wall_time, extra)))
    except KeyboardInterrupt:
        print("interrupted: the page was not written", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    extra = {seed: extra[seed] for seed in extra_seeds}
    text = render(cells, seconds, args.iters, args.seed, command, wall_time, methods=methods, extra=extra)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text, encoding="utf-8")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
