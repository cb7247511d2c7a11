"""The `config` command: the configuration a run would use, every key with its value, as TOML.

It answers "which keys are there and what are they now" (each method's gains included) for the
paper's setup, an experiment file, and ``--set`` on top; the output is itself an experiment file
(``ilcforce config > mine.toml``, edit, ``ilcforce simulate -c mine.toml``). Registered on the CLI's
``app`` when :mod:`ilcforce.cli` imports this module.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce.cli import _guard, _load, app, out

#: The comment above each section (methods' gain sections are named by the registry's titles).
SECTIONS = {
    "experiment": "name, seed, iterations",
    "plant": "the robot (model) and the true plant's change from an iteration on (perturbation)",
    "wall": "the constraint surface (SPEC section 2)",
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
    source = str(config) if config is not None else "the paper's setup (SPEC defaults)"
    header = f"ilcforce config: {source}" + (f" with {' '.join('--set ' + s for s in sets)}" if sets else "")
    out.print(toml_comment(header), highlight=False, markup=False, soft_wrap=True)
    out.print(dump_toml(cfg.to_dict(), comments), end="", highlight=False, markup=False, soft_wrap=True)
