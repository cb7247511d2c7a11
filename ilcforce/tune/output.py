"""The tuned experiment file: its text from the best trials, where it may be written, and the writing.

``ilcforce tune -o FILE`` checks FILE before any trial runs (:func:`check_output`): a new file in a folder
this process can write (or create), or with ``--overwrite`` an existing regular file that is no store,
no input of the run (the tuning file, its experiment, the model file and every file that names) and
no part of a tuning store, named so that it names an experiment. The text (:func:`tuned_experiment`) is
the tuning's experiment with each method's best gains and comments stating the budget; it is written
whole or not at all (:func:`write_output`).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ilcforce.config import ConfigError
from ilcforce.tune.spec import Tuning, TuneError


def run_inputs(tuning: Tuning) -> list[tuple[str, Path]]:
    """(what, path) of every file the run reads: the tuning file, its experiment, the experiment's
    model file and every file that names (MJCF includes, meshes, ...). An output must be none of them."""
    from ilcforce.plants import params_class

    inputs = [("the tuning file itself", tuning.path)] if tuning.path is not None else []
    inputs.append(("the tuning's experiment file (tune.experiment)", tuning.experiment))
    model = tuning.base.plant.model
    table = tuning.base.to_dict()["plant"].get(model, {})
    for key in getattr(params_class(model), "path_keys", ()):
        if isinstance(table.get(key), str):
            from ilcforce.plants.model_file import ModelFileError, referenced_files

            inputs.append((f"the experiment's model file (plant.{model}.{key})", Path(table[key])))
            try:
                inputs += [(f"a file the model file {table[key]} names", p) for p in referenced_files(table[key])]
            except ModelFileError:
                pass  # the run refuses the model itself
    return inputs


def _input_named(output: Path, tuning: Tuning) -> str | None:
    """Which input of the run ``output`` is, under any of its names (a link, a hard link, ``x/../x``):
    the same file (device and inode) as one the run reads; None if none."""
    try:
        target = os.stat(output)
    except OSError:
        return None
    for what, path in run_inputs(tuning):
        try:
            if os.path.samestat(target, os.stat(path)):
                return f"is {what}" if what.startswith("the tuning file") else f"is an input of this run: {what}"
        except OSError:
            continue
    return None


def _unwritable_folder(output: Path) -> str | None:
    """Why the tuned file could not be written beside ``output`` (its folder, or the nearest folder that
    exists above it, which the writer creates the rest in), or None: checked before any trial, so a
    read-only folder is refused before the tuning, not after it."""
    folder = output.absolute().parent
    while not os.path.lexists(folder) and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        return f"its folder {folder} is not a folder"
    ids = {"effective_ids": True} if os.access in os.supports_effective_ids else {}
    if os.access(folder, os.W_OK | os.X_OK, **ids):
        return None
    try:
        read_only = bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        read_only = False
    return f"cannot write in {folder} ({'a read-only file system' if read_only else 'permission denied'})"


def check_output(output: Path, tuning: Tuning, *, overwrite: bool) -> None:
    """TuneError (naming ``output``) unless the tuned experiment file may be written there: a new
    file in a folder this process may write, or with ``overwrite`` an existing regular file that is
    no store, no input of the run (:func:`run_inputs`) and no part of a tuning store; its name must
    make an experiment name. Checked before any trial runs."""
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
               else _input_named(output, tuning)
               or ("is a file of a tuning store" if any(is_tuning_store(p) for p in list(output.parents)[:2])
                   else None if overwrite else "exists; pass --overwrite to replace it (and start the tuning over)"))
        if why:
            raise TuneError(f"-o {output}: {why}; refusing to write the tuned experiment file there")
    why = _unwritable_folder(output)
    if why:
        raise TuneError(f"-o {output}: {why}; refusing to run a tuning whose tuned file cannot be written")
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


def tuned_experiment(tuning: Tuning, chosen: dict[str, dict | None], searches: dict[str, dict], cap, *,
                     name: str | None = None, folder: Path | None = None) -> str:
    """The experiment file of the tuning (its experiment with ``[tune.set]``, named ``name``) with each
    method's chosen gains (:func:`ilcforce.tune.heldout.choose`), headed by comments stating the tuning,
    each search's budget and convergence, the cap, and what each chosen point did on the held-out seeds.
    A method with no stable point under the cap keeps the experiment's gains and is listed under
    ``[tuning] withheld``: simulate, compare and studies refuse to run it with this file. ``folder``: where the
    file will be written (its model-file paths are then written relative to it; absolute without)."""
    from ilcforce.config_load import load_config, relative_paths
    from ilcforce.tomlfile import dump_toml, toml_comment
    from ilcforce.tune.heldout import NONE_UNDER_CAP
    from ilcforce.tune.objectives import per_axis_text
    from ilcforce.tune.search import outcome

    overrides = {**tuning.fixed, "experiment.name": name or f"{tuning.name}-tuned",
                 "experiment.description": f"{tuning.base.experiment.description}; gains tuned by ilcforce tune "
                                           f"({tuning.name})"}
    config = load_config(tuning.experiment, overrides)
    document = config.to_dict()
    # each method's section as its trials ran it: its own chosen gains on the experiment (a method family
    # shares keys, so one config holding every method's tuned gains would hand C3's to C3-leak)
    for method, point in chosen.items():
        if point is not None:
            document[method] = load_config(tuning.experiment, {**tuning.fixed, **point["gains"]}).to_dict()[method]
    if folder is not None:
        relative_paths(document, folder)
    withheld = [m for m in tuning.methods if chosen.get(m) is None]
    document["tuning"] = {"source": tuning.name, "withheld": withheld, "methods": list(tuning.methods),
                          "cap_reference": tuning.cap_reference,
                          "cap": [float(c) for c in cap] if cap else []}  # one per task axis
    source = tuning.path.name if tuning.path is not None else tuning.name
    b = tuning.budget
    lines = [f"Written by `ilcforce tune {source}`: the experiment {tuning.experiment.name} with [tune.set] "
             "and each method's gains chosen on held-out seeds (docs/tuning.md).",
             f"Search: error and settled chattering (two objectives), feasible only when {len(tuning.check_seeds)} "
             f"check seeds run {tuning.check_iterations} iterations without divergence or a growth-test flag; "
             f"scored on {len(tuning.seeds)} seeds x {tuning.iterations} iterations (the last {tuning.score_last}); "
             f"budget {b.base} + {b.per_dimension} x dimension trials, then on until the front's hypervolume "
             f"gains under {b.stop_gain:.0%} over the last quarter (at most {b.extend}x); TPE, seed "
             f"{tuning.sampler_seed}.",
             f"Chosen: the front point with the lowest error over {len(tuning.heldout_seeds)} held-out seeds x "
             f"{tuning.heldout_iterations} iterations that stayed stable with settled H at the last iteration "
             f"within the cap ({tuning.cap_factor:g} x {tuning.cap_reference} with the experiment's gains"
             + (f": {per_axis_text(tuning.axes, cap)})." if cap else ").")]
    for method in tuning.methods:
        state, point = searches.get(method, {}), chosen.get(method)
        search = f"{state.get('trials', '?')} trials ({outcome(state)}, front {state.get('front', 0)})"
        lines.append(f"{method}: {search}; " + (
            f"trial {point['trial']}: e_P {point['e_p']:.3g} m, e_F {point['e_f']:.3g} N, "
            f"{per_axis_text(tuning.axes, [point[f'h_{a}'] for a in tuning.axes])} (held-out medians)"
            if point is not None else f"{NONE_UNDER_CAP}: withheld"))
    return "\n".join(toml_comment(line) for line in lines) + "\n" + dump_toml(document)
