"""The tuned experiment file: its text from the best trials, where it may be written, and the writing.

``ilcforce tune -o FILE`` checks FILE before any trial runs (:func:`check_output`): a new file, or with
``--overwrite`` an existing regular file that is no store, no tuning file and no part of a tuning store,
named so that it names an experiment. The text (:func:`tuned_experiment`) is the tuning's experiment with
each method's best gains and comments stating the budget; it is written whole or not at all
(:func:`write_output`).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ilcforce.config import ConfigError
from ilcforce.tune.spec import Tuning, TuneError


def check_output(output: Path, tuning: Tuning, *, overwrite: bool) -> None:
    """TuneError (naming ``output``) unless the tuned experiment file may be written there: a new
    file, or with ``overwrite`` an existing regular file that is no store, no tuning file and no part
    of a tuning store; its name must make an experiment name. Checked before any trial runs."""
    from ilcforce.store.filecheck import is_hdf5_file
    from ilcforce.store.tuning import is_tuning_store

    try:
        info = os.lstat(output)
    except FileNotFoundError:
        info = None
    except OSError as exc:
        raise TuneError(f"-o {output}: cannot check the output file ({exc.strerror or exc})") from None
    if info is not None:
        why = ("is a folder" if stat.S_ISDIR(info.st_mode) else "is a symbolic link" if stat.S_ISLNK(info.st_mode)
               else "is not a regular file (a FIFO, a socket or a device)" if not stat.S_ISREG(info.st_mode)
               else "is an HDF5 store" if is_hdf5_file(output)
               else "is the tuning file itself" if tuning.path is not None and os.path.samefile(output, tuning.path)
               else "is a file of a tuning store" if any(is_tuning_store(p) for p in list(output.parents)[:2])
               else None if overwrite else "exists; pass --overwrite to replace it (and start the tuning over)")
        if why:
            raise TuneError(f"-o {output}: {why}; refusing to write the tuned experiment file there")
    if output.suffix != ".toml" or not output.stem or output.stem.startswith("."):
        raise TuneError(f"-o {output}: the tuned experiment file must be named <name>.toml")
    from ilcforce.config_load import load_config

    try:
        load_config(tuning.experiment, {**tuning.fixed, "experiment.name": output.stem})
    except ConfigError as exc:
        raise TuneError(f"-o {output}: its name cannot name an experiment ({exc})") from None


def write_output(output: Path, text: str, *, replace: bool) -> Path:
    from ilcforce.store.records import atomic_write

    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(output, text.encode(), replace=replace)  # a file that appeared meanwhile is kept too
    except OSError as exc:
        raise TuneError(f"-o {output}: cannot write the tuned experiment file ({exc.strerror or exc}); every "
                        "trial is stored, and a file that was there is unchanged") from None
    return output


def tuned_experiment(tuning: Tuning, best: dict[str, dict], baseline: dict[str, dict] | None = None, *,
                     name: str | None = None, stored: dict[str, int] | None = None) -> str:
    """The experiment file of the tuning (its experiment with ``[tune.set]``, named ``name``) with
    each method's best trial's gains, headed by comments stating the tuning file and budget. The
    experiment keeps its own iteration count (the tuning's horizon only judged the gains)."""
    from ilcforce.config_load import load_config
    from ilcforce.tomlfile import dump_toml, toml_comment

    overrides = {**tuning.fixed, "experiment.name": name or f"{tuning.name}-tuned",
                 "experiment.description": f"{tuning.base.experiment.description}; gains tuned by ilcforce tune "
                                           f"({tuning.name})"}
    config = load_config(tuning.experiment, overrides)
    document = config.to_dict()
    # each method's section as its trials ran it: its own best gains on the experiment (a method family
    # shares keys, so one config holding every method's tuned gains would hand C3's to C3-leak)
    for method, record in best.items():
        document[method] = load_config(tuning.experiment, {**tuning.fixed, **record["gains"]}).to_dict()[method]
    source = tuning.path.name if tuning.path is not None else tuning.name
    lines = [f"Written by `ilcforce tune {source}`: the experiment {tuning.experiment.name} with [tune.set] "
             f"and each tuned method's best gains.",
             f"Budget per method: {tuning.trials} trials (trial 0 = the experiment's gains) x {len(tuning.seeds)} "
             f"seeds x {tuning.iterations} iterations; sampler TPE, seed {tuning.sampler_seed}"
             + (" (this run's budget; the counts below include trials stored by runs with another)."
                if any(c != tuning.trials for c in (stored or {}).values()) else "."),
             f"Objective ({tuning.objective}): median over seeds of the mean over iterations "
             f"{tuning.score_iterations - tuning.score_last}..{tuning.score_iterations - 1} of log10(e_P/1 mm) "
             f"and/or log10(e_F/1 N) (RMS norms); a divergence anywhere in the horizon fails the trial."]
    for method in tuning.methods:
        first, record = (baseline or {}).get(method), best.get(method)
        count = (stored or {}).get(method, "the")
        was = ("failed" if first["value"] is None else f"{first['value']:.4g}") if first else "not run"
        lines.append(f"{method}: best trial {record['number']} of {count} stored, objective {record['value']:.4g} "
                     f"(trial 0, the experiment's gains: {was})" if record is not None else
                     f"{method}: UNTUNED: every one of its {count} stored trials failed; its gains are the "
                     "experiment's own")
    return "\n".join(toml_comment(line) for line in lines) + "\n" + dump_toml(document)
