"""The `config` command: the configuration a run would use, every key with its value, as TOML.

It answers "which keys are there and what are they now" (each method's gains included) for the
paper's setup, an experiment file, and ``--set`` on top; the output is itself an experiment file
(``ilcforce config > mine.toml``, edit, ``ilcforce simulate -c mine.toml``). Registered on the CLI's
``app`` when :mod:`ilcforce.cli` imports this module.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce.cli.base import _guard, _load, app

#: The comment above each section (methods' gain sections are named by the registry's titles).
SECTIONS = {
    "experiment": "name, seed, iterations (on the command line: --seed, --iters)",
    "plant": "the robot (model) and the true plant's change from an iteration on (perturbation)",
    "wall": "the constraint surface (docs/model.md#wall)",
    "reference": "the desired position and force",
    "simulation": "integration, estimates and bounds",
    "noise": "measurement noise and disturbance (0 turns a source off)",
    "surface": "S and the lambdas of eq. (8)",
}


@app.command()
@_guard
def config(
    config: Annotated[Optional[Path], typer.Option("--config", "-c", help="experiment TOML (default: the paper's setup)")] = None,
    seed: Annotated[Optional[int], typer.Option("--seed", help="random seed (disturbance and noise)")] = None,
    iters: Annotated[Optional[int], typer.Option("--iters", "-n", help="number of iterations")] = None,
    sets: Annotated[Optional[list[str]], typer.Option("--set", help="override a config value, e.g. --set c3.eta=2 (repeatable)")] = None,
) -> None:
    """Print the resolved configuration as TOML: every key (`--set section.key=value`) and its value."""
    from ilcforce.controllers import REGISTRY
    from ilcforce.tomlfile import dump_toml, toml_comment

    cfg = _load(config, seed, iters, sets)
    comments = dict(SECTIONS)
    comments.update({name: f"{spec.title}: gains" for name, spec in REGISTRY.items()})
    given = [*(["--config", str(config)] if config is not None else []),
             *(["--seed", str(seed)] if seed is not None else []),
             *(["--iters", str(iters)] if iters is not None else []),
             *[arg for text in sets or [] for arg in ("--set", text)]]
    header = "ilcforce config" + (f" {shlex.join(given)}" if given else ": the paper's setup (the defaults of docs/model.md)")
    # plain ASCII on stdout, not through rich (which would turn ':smile:' in a string into an emoji)
    sys.stdout.write(toml_comment(header) + "\n" + dump_toml(cfg.to_dict(), comments))
    sys.stdout.flush()
