"""The `analyze` command: the lifted-system check of a learning law (:mod:`ilcforce.theory.lifted`,
docs/model.md#lifted), printed as a table of per-band growth under the spectral radius, the largest
singular value and the memory's drift at t = 0. No science here."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce.cli.base import CliError, _guard, _load, _say, app, show, table


@app.command()
@_guard
def analyze(
    method: Annotated[str, typer.Option("--method", "-m", help="a learning method (c2, c3, c3-leak, pd-ilc, c2-robust, c3-robust, ...)")] = "c2",
    config: Annotated[Optional[Path], typer.Option("--config", "-c", help="experiment TOML (default: the paper's setup)")] = None,
    sets: Annotated[Optional[list[str]], typer.Option("--set", help="override a config value, e.g. --set simulation.sample_time=1e-3 (repeatable)")] = None,
    at: Annotated[int, typer.Option("--at", help="linearise around the memory of the noise-free run after this many iterations")] = 20,
    bands: Annotated[str, typer.Option("--bands", help="band edges, Hz (the last band ends at the Nyquist frequency)")] = "0,100,400,800,1600,5000",
    full: Annotated[Optional[bool], typer.Option("--full/--matrix-free", help="the full lifted matrix (one iteration per column) or matrix-free (default: full up to 5000 columns)")] = None,
    step: Annotated[str, typer.Option("--step", help="finite-difference step: 'noise' (the memory change the experiment's noise makes in one iteration: a switching term's describing-function amplitude), a fraction of each memory column's largest value, or 'auto' (noise where there is some)")] = "auto",
) -> None:
    """Predict a learning law's convergence from its lifted map (noise off): spectral radius, largest
    singular value, per-band growth per iteration and the drift at t = 0."""
    from ilcforce.theory import lifted

    try:
        edges = sorted({float(b) for b in bands.split(",") if b.strip()})
    except ValueError:
        raise CliError(f"--bands takes comma-separated frequencies in Hz, got {bands!r}") from None
    if not edges or edges[0] < 0:
        raise CliError(f"--bands takes frequencies >= 0 Hz, got {bands!r}")
    if step not in ("auto", "noise"):
        try:
            step = float(step)
        except ValueError:
            raise CliError(f"--step takes 'auto', 'noise' or a number in (0, 1), got {step!r}") from None
    cfg = _load(config, None, None, sets)

    def progress(done: int, total: int) -> None:
        if done % 500 == 0 or done == total:
            _say(f"lifted matrix: {done}/{total} columns", stderr=True)

    try:
        check = lifted.analyze(cfg, method, at=at, bands=edges, full=full, step=step, progress=progress)
    except lifted.AnalysisError as exc:
        raise CliError(str(exc)) from None
    _say(f"{check.experiment} / {check.method}: the lifted map at j = {check.at} (noise off), Ts = "
         f"{check.sample_time:g} s, {check.n_control} samples x {check.width} memory columns")
    grid = table("growth of the settled memory's change per iteration")
    for col in ("band (Hz)", "growth", "prediction"):
        grid.add_column(col, justify="right", no_wrap=True)
    for low, high, growth in check.band_growth:
        grid.add_row(f"{low:g}-{high:g}", f"{growth:.4f}", "grows" if growth > 1 + 1e-3 else "bounded")
    show(grid)
    how = "full matrix" if check.full else "matrix-free"
    rho_how = ("every diagonal block" if check.full else "64 sampled diagonal blocks") if check.causal else \
        "not triangular (a non-causal filter): the largest band growth"
    _say(f"spectral radius {check.spectral_radius:.6f} ({check.asymptotic}; {rho_how})")
    sv = "exact" if check.full else "the largest band gain"
    _say(f"largest singular value {check.max_singular_value:.4f} ({'monotonic in the 2-norm' if check.max_singular_value < 1 else 'not monotonic'}; {sv})")
    drift = ", ".join(f"{d:+.4g}" for d in check.drift_t0)
    _say(f"memory change at t = 0 per iteration: {drift} (memory units; non-zero: an inconsistent start drifts without bound)")
    _say(f"predicted {'bounded' if check.bounded else 'unbounded'}; {how}, {check.simulated_iterations} simulated "
         f"iterations, {check.seconds:.1f} s")
