"""A study from command-line options (Hydra's ``-m key=a,b,c`` habit), without writing a study file:

    ilcforce study -m c3 --sweep c3.eta=1,2,5 --seeds 0-19 [--sweep KEY=V1,V2 ...] [--set KEY=V] [-c EXPERIMENT]

The options become the study file they stand for (:func:`study_text`): ``--methods`` its ``methods``,
``--seeds`` its ``seeds``, each ``--sweep`` a key of ``[study.sweep]`` (several make the full factorial
grid, the first slowest), each ``--set`` a key of ``[study.set]``, ``--config`` its ``experiment`` (the
paper's setup without). The study is named after that content (:func:`study_name`: the same options give
the same name, so a rerun continues the same store), validated as any study file is, and run as one; the
file is saved beside its store as ``<results>/studies/<name>.toml`` (:func:`save_study_file`), so the
store and the file that made it sit together and ``ilcforce study <results>/studies/<name>.toml`` runs
it again.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

from ilcforce.config import ConfigError
from ilcforce.config_load import parse_override
from ilcforce.study.spec import Study, StudyError, build_study, parse_seeds
from ilcforce.tomlfile import parse_toml, resolve_toml

#: how many characters of the swept keys a study's name shows before its content hash
_KEYS_SHOWN = 60


def split_values(text: str) -> list[str]:
    """``"1,2,5"`` -> ["1", "2", "5"]: the commas outside brackets, braces and quotes separate values
    (``"[1, 2],[3, 4]"`` is two lists)."""
    items, depth, quote, start = [], 0, "", 0
    for i, char in enumerate(text):
        if quote:
            if char == quote:
                quote = ""
        elif char in "\"'":
            quote = char
        elif char in "[{":
            depth += 1
        elif char in "]}":
            depth -= 1
        elif char == "," and depth == 0:
            items.append(text[start:i])
            start = i + 1
    items.append(text[start:])
    return [item.strip() for item in items]


def parse_sweep(text: str) -> tuple[str, list]:
    """``"c3.eta=1,2,5"`` -> ("c3.eta", [1, 2, 5]); each value read as ``--set`` reads one (TOML, else a
    string). StudyError (one line) for no ``=``, no key or an empty value."""
    if "=" not in text:
        raise StudyError(f"--sweep expects KEY=V1,V2,... (e.g. c3.eta=1,2,5), got {text!r}")
    key, raw = (part.strip() for part in text.split("=", 1))
    if not key:
        raise StudyError(f"--sweep expects KEY=V1,V2,..., got {text!r}")
    items = split_values(raw)
    if any(item == "" for item in items):
        raise StudyError(f"--sweep {key}: an empty value in {raw!r} (values are separated by commas)")
    try:
        return key, [parse_override(f"{key}={item}")[1] for item in items]
    except ConfigError as exc:
        raise StudyError(f"--sweep {key}: {exc}") from None


def parse_seeds_option(text: str) -> str | list[int]:
    """``--seeds``: ``"0-19"`` (a range, inclusive) or ``"0,3,7"`` (a list) -> the study file's value."""
    text = text.strip()
    if re.fullmatch(r"\d+\s*-\s*\d+", text):
        return re.sub(r"\s", "", text)
    items = split_values(text)
    if not all(re.fullmatch(r"\d+", item) for item in items):
        raise StudyError(f"--seeds must be a range a-b or a comma-separated list of integers >= 0, got {text!r}")
    return [int(item) for item in items]


def _toml(value) -> str:
    """A value as TOML (what tomllib reads back as the same value)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)  # inf and nan read back as TOML's inf and nan
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{json.dumps(k)} = {_toml(v)}" for k, v in value.items()) + " }"
    raise StudyError(f"cannot write {value!r} into a study file")


def study_content(*, methods: list[str] | None, seeds: str, sweeps: list[str], sets: list[str],
                  experiment: Path | None) -> dict:
    """The [study] table the options stand for, without its name: methods, seeds, experiment, set, sweep.
    Seeds are written as a range when they are one, so ``0-2`` and ``0,1,2`` are one study."""
    if seeds is None:
        raise StudyError("--seeds is missing (e.g. --seeds 0-19)")
    parsed = parse_seeds(parse_seeds_option(seeds))
    contiguous = len(parsed) > 1 and parsed[-1] - parsed[0] == len(parsed) - 1
    table: dict = {}
    if experiment is not None:
        found = Path(resolve_toml(experiment))  # a path, or a shipped experiment's name ("serial2r")
        if not found.is_file():
            raise StudyError(f"--config: no experiment file {experiment}")
        table["experiment"] = str(found.resolve())  # the saved study file reads it from anywhere
    if methods is not None:
        table["methods"] = list(methods)
    table["seeds"] = f"{parsed[0]}-{parsed[-1]}" if contiguous else list(parsed)
    fixed = {}
    for text in sets or ():
        try:
            key, value = parse_override(text)
        except ConfigError as exc:
            raise StudyError(str(exc)) from None
        fixed[key] = value
    sweep: dict = {}
    for text in sweeps or ():
        key, values = parse_sweep(text)
        if key in sweep:
            raise StudyError(f"--sweep {key} is given twice; give its values once (--sweep {key}=V1,V2,...)")
        sweep[key] = values
    for flag, keys in (("--set", fixed), ("--sweep", sweep)):
        if "experiment.seed" in keys:
            raise StudyError(f"{flag} experiment.seed: a study's seeds are --seeds (e.g. --seeds 0-19)")
    if fixed:
        table["set"] = fixed
    if sweep:
        table["sweep"] = sweep
    return table


def study_name(content: dict) -> str:
    """A name for the study from its content alone: ``sweep-<swept keys>-<10 hex of its hash>`` (``seeds-``
    without a sweep). The same content always gives the same name; different content, another."""
    digest = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:10]
    keys = "-".join(content.get("sweep", {}))
    shown = re.sub(r"[^A-Za-z0-9._-]", "_", keys)[:_KEYS_SHOWN].strip("._-")
    return f"sweep-{shown}-{digest}" if shown else f"seeds-{digest}"


def _description(content: dict) -> str:
    """One line from the content: "from the command line: c3; c3.eta = 1, 2, 5; seeds 0-19"."""
    parts = [", ".join(content["methods"]) if "methods" in content else "every method"]
    parts += [f"{key} = {', '.join(_toml(v) for v in values)}" for key, values in content.get("sweep", {}).items()]
    seeds = content["seeds"]
    parts.append(f"seeds {seeds}" if isinstance(seeds, str) else f"seeds {', '.join(map(str, seeds))}")
    return "from the command line: " + "; ".join(parts)


def study_text(name: str, content: dict) -> str:
    """The study file of ``content`` named ``name`` (TOML; a fixed text for the same content)."""
    lines = ["# written by `ilcforce study --sweep/--seeds` (ilcforce.study.options): the study that command ran;",
             "# `ilcforce study` with this file runs it again (and continues its store)",
             "[study]", f"name = {_toml(name)}",
             f"description = {_toml(_description(content))}"]
    for key in ("experiment", "methods", "seeds"):
        if key in content:
            lines.append(f"{key} = {_toml(content[key])}")
    for table in ("set", "sweep"):
        if table in content:
            lines += ["", f"[study.{table}]"] + [f"{json.dumps(k)} = {_toml(v)}" for k, v in content[table].items()]
    return "\n".join(lines) + "\n"


def study_from_options(results: Path | str, *, methods: list[str] | None, seeds: str | None, sweeps: list[str],
                       sets: list[str], experiment: Path | None) -> Study:
    """The validated study the options stand for, its ``path`` the file it is saved as
    (``<results>/studies/<name>.toml``, not written yet: :func:`save_study_file`). StudyError (one line)."""
    content = study_content(methods=methods, seeds=seeds, sweeps=sweeps, sets=sets, experiment=experiment)
    name = study_name(content)
    text = study_text(name, content)
    path = Path(results) / "studies" / f"{name}.toml"
    try:
        return build_study(parse_toml(text), source=text, path=path)
    except StudyError as exc:
        raise StudyError(f"the study of --sweep/--seeds: {exc}") from None


def save_study_file(study: Study) -> bool:
    """Write ``study.source`` to ``study.path`` (whole or not at all) unless that file holds it already;
    True if written. StudyError when another file is there: it is never replaced."""
    from ilcforce.store.records import atomic_write

    path = Path(study.path)
    try:
        if path.read_text(encoding="utf-8") == study.source:
            return False
    except FileNotFoundError:
        pass
    except (OSError, UnicodeDecodeError) as exc:
        raise StudyError(f"{path}: cannot be read to compare ({getattr(exc, 'strerror', None) or exc})") from None
    else:
        raise StudyError(f"{path} exists with other content; it is the study file of the store beside it "
                         "(move it away to run this study)")
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        atomic_write(path, study.source.encode("utf-8"), replace=False)
    except FileExistsError:  # written meanwhile by a concurrent run of the same command
        return save_study_file(study)
    return True
