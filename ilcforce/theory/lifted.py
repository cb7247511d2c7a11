"""The lifted-system check of a learning law (docs/model.md#lifted): what theory says about its convergence.

A learning method maps the memory one iteration reads, m_j (n_control samples x the memory's columns),
to the one the next reads: m_{j+1} = F_j(m_j). Around a memory m* (the noise-free run's after
``at`` iterations) the map is linearised: m_{j+1} - F(m*) ~ T (m_j - m*), with T the lifted matrix
(Bristow, Tharayil and Alleyne 2006; Amann, Owens and Rogers 1996 for the norm-optimal design).
T is not derived by hand: it is the derivative of the very iteration the simulator runs (the
sampled-data loop, the wall, the acceleration scheme, the law's feedback part and its memory
update), taken by finite differences, so the check and the simulation cannot disagree about the
model. What is reported:

* ``spectral_radius``: max |eig(T)|. T is block lower-triangular (the loop is causal: the memory at
  sample l changes nothing before l; the full matrix's upper part is reported as a check), so its
  eigenvalues are those of the per-sample diagonal blocks D_l = dm_{j+1}(l) / dm_j(l) (all of them
  from the full matrix; matrix-free, 64 evenly spaced ones, each from the memory perturbed there alone). Below 1:
  the iteration converges asymptotically; at 1 (a law whose update at l does not see its own torque
  at l, e.g. C2's current-iteration update, since sigma has relative degree one): only marginally,
  and what happens over hundreds of iterations is set by the rest of T.
* ``max_singular_value``: ||T||_2, below 1 the 2-norm of the memory's change shrinks at every
  iteration (monotonic convergence). Exact from the full matrix; on a grid too fine for the full
  matrix, the largest band gain (below), which is its limit for a slowly varying T on a long horizon.
* ``band_growth``: the per-iteration growth of the memory's change in a frequency band, on the
  settled part of the horizon: power iteration of W P_b T P_b W (P_b keeps the band's DFT bins, W
  the samples from ``settled_from`` on). The measured counterpart is the growth of the band's
  energy in m_{j+1} - m_j over a long noise-free run (:func:`measured_band_growth`).
* ``drift_t0``: F(m*) - m* at t = 0. The state at t = 0 is the same at every iteration, so the
  memory's change there does not depend on the memory (T's first block row is the identity for a
  current-iteration law): where the start is not consistent the memory at t = 0 drifts by this
  much per iteration, without bound.

Switching terms (sgn sigma of C3 and its variants) are differentiated as they are: a finite difference
across a sign change is a secant, the describing-function gain of the switch at the step's amplitude
(4 alpha / (pi A) for alpha sgn at amplitude A), which grows without bound as the step shrinks. So the
step is, by default, the amplitude at which the memory is perturbed in a real run: per memory column, the
RMS change the experiment's noise makes to the next memory in one iteration (``step="noise"``). For a
smooth law (C2, PD-ILC, C2-robust) this gives the small-step result to four digits; for C3 a step of
1e-6 of the memory's scale gives gains of 50-120 per iteration that no run shows. The laws with a hard
cap (C3-robust's alpha_hat) are linearised on whichever side of the cap m* is.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ilcforce.config import Config
from ilcforce.records import STATUS_COMPLETE

#: the default bands (Hz) of the band growth; the last band ends at the Nyquist frequency
DEFAULT_BANDS = (0.0, 100.0, 400.0, 800.0, 1600.0, 5000.0)
#: the full lifted matrix is made (one simulated iteration per column) up to this many columns
FULL_COLUMNS = 5000
#: the finite-difference step, relative to each memory column's largest value
STEP = 1e-6
#: power iterations per band
POWER_ITERATIONS = 80
#: the largest |T| above the block diagonal that still counts as causal (finite-difference round-off)
CAUSAL_TOLERANCE = 1e-6


class AnalysisError(ValueError):
    """The check cannot be made as asked (one line: what and why)."""


def noise_free(config: Config) -> Config:
    """``config`` without disturbance or sensor noise: the lifted map is the deterministic iteration."""
    return dataclasses.replace(config, noise=dataclasses.replace(config.noise, scale=0.0))


def _settled_window(n_control: int, sample_time: float, settled_from: float) -> np.ndarray:
    return (np.arange(n_control) * sample_time >= settled_from).astype(np.float64)


def band_projector(n_control: int, sample_time: float, low: float, high: float) -> Callable[[np.ndarray], np.ndarray]:
    """P_b: keeps the DFT bins with low <= f < high (Hz) of each column of an (n_control, width) array."""
    freqs = np.fft.rfftfreq(n_control, sample_time)
    keep = ((freqs >= low) & (freqs < high)).astype(np.float64)
    if not keep.any():
        raise AnalysisError(f"the band {low:g}-{high:g} Hz holds no frequency of a {n_control}-sample grid at "
                            f"Ts = {sample_time:g} s (Nyquist {0.5 / sample_time:g} Hz)")

    def project(x: np.ndarray) -> np.ndarray:
        return np.fft.irfft(np.fft.rfft(x, axis=0) * keep[:, None], n=n_control, axis=0)

    return project


def flatten(memory: dict[str, np.ndarray], blocks: dict[str, tuple[int, int, str]], n_control: int,
            width: int) -> np.ndarray:
    """A learned state (name -> (n_control, columns) block) as one sample-major vector of the memory layout."""
    grid = np.empty((n_control, width))
    for key, (start, stop, _unit) in blocks.items():
        grid[:, start:stop] = np.asarray(memory[key], dtype=np.float64).reshape(n_control, stop - start)
    return grid.ravel()


def bands_of(edges: Sequence[float], n_control: int, sample_time: float):
    """(low, high, P_b) per band between consecutive ``edges`` (Hz) below the Nyquist frequency, the last band
    ending there."""
    nyquist = 0.5 / sample_time
    cuts = [b for b in edges if b < nyquist] + [nyquist * (1 + 1e-12)]
    return [(float(low), float(min(high, nyquist)), band_projector(n_control, sample_time, low, high))
            for low, high in zip(cuts[:-1], cuts[1:])]


@dataclass
class IterationMap:
    """F_j, one noise-free iteration of ``method`` as a map of the memory it reads (flattened,
    sample-major: index = sample * width + column), with the memory m* it is linearised around."""

    config: Config
    method: str
    iteration: int
    blocks: dict[str, tuple[int, int, str]]
    base: np.ndarray  # m*, flattened
    width: int
    calls: int = 0

    def __post_init__(self) -> None:
        from ilcforce.experiment import iteration_inputs, make_controller
        from ilcforce.simulate import prepare_setup

        self._controller = make_controller(self.config, self.method)
        self._inputs = prepare_setup(iteration_inputs(self.config, self.iteration, self.config.reference_samples()),
                                     self._controller)
        self.base_image = self(self.base)

    @property
    def n_control(self) -> int:
        return self.config.n_control

    def unflatten(self, m: np.ndarray) -> dict[str, np.ndarray]:
        grid = m.reshape(self.n_control, self.width)
        return {key: grid[:, start:stop] for key, (start, stop, _unit) in self.blocks.items()}

    def flatten(self, memory: dict[str, np.ndarray]) -> np.ndarray:
        return flatten(memory, self.blocks, self.n_control, self.width)

    def __call__(self, m: np.ndarray) -> np.ndarray:
        """F_j(m): the memory the next iteration reads, after one iteration that read ``m``."""
        from ilcforce.simulate import run_iteration

        controller = self._controller
        controller.restore(self.unflatten(m))
        mem_prev, mem_new = controller.begin_iteration(self.iteration)
        record = run_iteration(self._inputs, controller, mem_prev, mem_new)
        self.calls += 1
        if record.status != STATUS_COMPLETE:
            raise AnalysisError(f"{self.method}: the iteration diverged ({record.reason}) at the linearisation "
                                f"point; linearise earlier (--at) or where the method runs")
        controller.end_iteration(record)
        return self.flatten(controller.learned_state())


def iteration_map(config: Config, method: str, at: int = 20) -> IterationMap:
    """The noise-free iteration map of ``method`` at iteration ``at``, linearised around the memory the
    noise-free run reaches after ``at`` iterations (0: the zero memory of the first iteration)."""
    from ilcforce.experiment import canonical, make_controller, simulate_iterations

    method = canonical(method)
    config = noise_free(config)
    controller = make_controller(config, method)
    blocks = dict(controller.memory_layout)
    if not blocks:
        raise AnalysisError(f"{method} learns nothing from one iteration to the next (no memory): there is no "
                            "lifted map to check")
    width = max(stop for _start, stop, _unit in blocks.values())
    if at < 0:
        raise AnalysisError(f"--at must be >= 0, got {at}")
    memory = {key: np.zeros((config.n_control, stop - start)) for key, (start, stop, _u) in blocks.items()}
    if at > 0:
        warm = dataclasses.replace(config, experiment=dataclasses.replace(config.experiment, iterations=at))
        for record in simulate_iterations(warm, method):
            if record.status != STATUS_COMPLETE:
                raise AnalysisError(f"{method} diverges at iteration {record.iteration} of the noise-free run, "
                                    f"before the linearisation point j = {at}: choose an earlier --at")
            memory = record.memory
    return IterationMap(config, method, at, blocks, flatten(memory, blocks, config.n_control, width), width)


def noise_amplitude(fmap: IterationMap, config: Config) -> np.ndarray:
    """Per memory column, the RMS over the samples of the change the experiment's noise makes to the next
    memory in one iteration from m*: F_noisy(m*) - F(m*). The amplitude at which a switching term's
    describing-function gain is taken (``step="noise"``): the size of what perturbs the memory in a real run."""
    noisy = IterationMap(config, fmap.method, fmap.iteration, fmap.blocks, fmap.base, fmap.width)
    fmap.calls += noisy.calls
    change = (noisy.base_image - fmap.base_image).reshape(fmap.n_control, fmap.width)
    amplitude = np.sqrt(np.mean(np.square(change), axis=0))
    if not np.any(amplitude > 0):
        raise AnalysisError(f"{fmap.method}: the experiment's noise does not reach the memory (noise.scale 0?); "
                            "give a relative --step instead of 'noise'")
    # a column the noise does not move (a memory held at its bound, e.g. C3-robust's alpha_hat at alpha_max):
    # the small relative step, at which such a column's derivative is its own (zero at a hard bound)
    return np.where(amplitude > 0, amplitude, _step(fmap, STEP))


def _step(fmap: IterationMap, relative: float | np.ndarray) -> np.ndarray:
    """The finite-difference step per memory column: ``relative`` x the column's largest |m*| (at
    least ``relative`` x 1 in its unit), or the given per-column amplitudes (an array)."""
    if isinstance(relative, np.ndarray):
        return relative
    grid = fmap.base.reshape(fmap.n_control, fmap.width)
    scale = np.maximum(np.abs(grid).max(axis=0), 1.0)
    return relative * scale


def apply_lifted(fmap: IterationMap, x: np.ndarray, relative: float = 1e-6) -> np.ndarray:
    """T x by a forward difference: (F(m* + eps x) - F(m*)) / eps, eps sized to the memory's scale."""
    steps = np.tile(_step(fmap, relative), fmap.n_control)
    peak = np.max(np.abs(x) / steps)
    if peak == 0.0:
        return np.zeros_like(x)
    eps = 1.0 / peak
    return (fmap(fmap.base + eps * x) - fmap.base_image) / eps


def lifted_matrix(fmap: IterationMap, relative: float = 1e-6,
                  progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """T, one forward difference per column (n_control x width columns, one simulated iteration each)."""
    size = fmap.n_control * fmap.width
    if size > FULL_COLUMNS:
        raise AnalysisError(f"the full lifted matrix has {size} columns (one simulated iteration each; at most "
                            f"{FULL_COLUMNS}): use the matrix-free check or a coarser sample time")
    steps = np.tile(_step(fmap, relative), fmap.n_control)
    out = np.empty((size, size))
    for i in range(size):
        m = fmap.base.copy()
        m[i] += steps[i]
        out[:, i] = (fmap(m) - fmap.base_image) / steps[i]
        if progress is not None:
            progress(i + 1, size)
    return out


def band_growth(apply: Callable[[np.ndarray], np.ndarray], n_control: int, width: int, sample_time: float,
                bands: Sequence[float], settled_from: float, iterations: int = POWER_ITERATIONS,
                seed: int = 0) -> list[tuple[float, float, float]]:
    """(low, high, growth) per band: power iteration of W P_b T P_b W from a random band-limited start."""
    window = _settled_window(n_control, sample_time, settled_from)[:, None]
    rng = np.random.default_rng(seed)
    out = []
    for low, high, project in bands_of(bands, n_control, sample_time):
        x = window * project(rng.standard_normal((n_control, width)))
        growth = math.nan
        for _ in range(iterations):
            norm = np.linalg.norm(x)
            y = window * project(apply(x.ravel() / norm).reshape(n_control, width))
            growth = float(np.linalg.norm(y))
            x = y
        out.append((low, high, growth))
    return out


def diagonal_blocks(matrix: np.ndarray, n_control: int, width: int) -> np.ndarray:
    """The per-sample (width x width) diagonal blocks of a sample-major lifted matrix."""
    idx = np.arange(n_control)[:, None] * width + np.arange(width)[None, :]
    return matrix[idx[:, :, None], idx[:, None, :]]


@dataclass(frozen=True)
class LiftedCheck:
    """What :func:`analyze` found (docs/model.md#lifted)."""

    method: str
    experiment: str
    at: int
    sample_time: float
    n_control: int
    width: int
    full: bool  # the full matrix was made (else matrix-free)
    spectral_radius: float
    max_singular_value: float
    upper_part: float  # max |T| above the block diagonal (0 for a causal loop); matrix-free: at the sampled columns
    band_growth: tuple[tuple[float, float, float], ...]
    drift_t0: tuple[float, ...]  # F(m*) - m* at t = 0, per memory column
    radius_t0: float  # max |eig| of the diagonal block at t = 0 (1: the memory there is not corrected)
    seconds: float
    simulated_iterations: int

    @property
    def causal(self) -> bool:
        """T is block lower-triangular (to round-off): no memory sample changes an earlier one's update."""
        return self.upper_part <= CAUSAL_TOLERANCE

    @property
    def asymptotic(self) -> str:
        if self.spectral_radius < 1 - 1e-9:
            return "converges"
        return "marginal (rho = 1)" if self.spectral_radius <= 1 + 1e-9 else "diverges"

    @property
    def bounded(self) -> bool:
        """Predicted bounded over a long run: no band grows, and the memory at t = 0 does not drift (it
        has no change there, or the change there is corrected: a t = 0 block of radius below 1, or a
        non-causal T, whose t = 0 row is not that block alone)."""
        grows = any(g > 1.0 + 1e-3 for _l, _h, g in self.band_growth)
        drifts = any(abs(d) > 1e-9 for d in self.drift_t0) and self.causal and self.radius_t0 >= 1.0 - 1e-9
        return not grows and not drifts


def sampled_diagonal(fmap: IterationMap, samples: int = 64, relative: float = 1e-6) -> tuple[float, float, float]:
    """(max |eig(D_l)|, causality residual, max |eig(D_0)|) matrix-free, over ``samples`` evenly spaced samples l: the memory
    perturbed at sample l alone (one simulated iteration per memory column) gives D_l's column at l, and the
    next memory before l, which a causal loop leaves as it was (the residual: its largest relative change)."""
    n, width = fmap.n_control, fmap.width
    steps = _step(fmap, relative)
    rho, residual, first = 0.0, 0.0, math.nan
    for l in np.unique(np.linspace(0, n - 1, min(samples, n)).round().astype(int)):
        block = np.empty((width, width))
        for c in range(width):
            m = fmap.base.copy()
            m[l * width + c] += steps[c]
            change = (fmap(m) - fmap.base_image).reshape(n, width) / steps[c]
            block[:, c] = change[l]
            if l > 0:
                residual = max(residual, float(np.max(np.abs(change[:l]))))
        radius = float(np.max(np.abs(np.linalg.eigvals(block))))
        rho = max(rho, radius)
        first = radius if l == 0 else first
    return rho, residual, first


def analyze(config: Config, method: str, *, at: int = 20, bands: Sequence[float] = DEFAULT_BANDS,
            full: bool | None = None, settled_from: float | None = None, step: float | str = "auto",
            progress: Callable[[int, int], None] | None = None) -> LiftedCheck:
    """The lifted check of ``method`` on ``config`` (noise off), linearised at iteration ``at``.
    ``full`` None: the full matrix when it has at most :data:`FULL_COLUMNS` columns. ``step``: the finite
    differences' step, "noise" (per memory column, the RMS change the experiment's noise makes in one iteration:
    the amplitude at which a switching term's describing-function gain is taken; for a smooth law the same
    result as a small step), a fraction of each column's largest value, or "auto" ("noise" where the experiment
    has noise, else :data:`STEP`)."""
    from ilcforce.metrics import SETTLED_FROM

    settled = SETTLED_FROM if settled_from is None else settled_from
    start = time.perf_counter()
    fmap = iteration_map(config, method, at)
    if step in ("noise", "auto"):  # the describing-function amplitude: what the experiment's noise does in one iteration
        noisy = dataclasses.replace(config, experiment=dataclasses.replace(
            config.experiment, iterations=max(config.experiment.iterations, at + 1)))
        try:
            step = noise_amplitude(fmap, noisy)
        except AnalysisError:
            if step == "noise":
                raise
            step = STEP  # "auto" on a noise-free experiment: a small step (exact for a smooth law)
    elif not (isinstance(step, float) and 0 < step < 1):
        raise AnalysisError(f"the finite-difference step is 'noise' or a fraction in (0, 1) of each memory "
                            f"column's largest value, got {step!r}")
    n, width, ts = fmap.n_control, fmap.width, fmap.config.simulation.sample_time
    size = n * width
    use_full = size <= FULL_COLUMNS if full is None else full
    drift = fmap.base_image.reshape(n, width)[0] - fmap.base.reshape(n, width)[0]
    if use_full:
        matrix = lifted_matrix(fmap, step, progress=progress)
        blocks = diagonal_blocks(matrix, n, width)
        radii = [float(np.max(np.abs(np.linalg.eigvals(b)))) for b in blocks]
        rho, first = max(radii), radii[0]
        mask = np.ones((size, size), dtype=bool)
        for i in range(n):  # the block lower triangle, diagonal blocks included
            mask[i * width:(i + 1) * width, :(i + 1) * width] = False
        upper = float(np.max(np.abs(matrix[mask]))) if mask.any() else 0.0
        sigma = float(np.linalg.norm(matrix, 2))
        growth = band_growth(lambda x: matrix @ x, n, width, ts, bands, settled)
    else:
        growth = band_growth(lambda x: apply_lifted(fmap, x, step), n, width, ts, bands, settled)
        rho, upper, first = sampled_diagonal(fmap, relative=step)
        sigma = max(g for _l, _h, g in growth)  # ||T||_2's long-horizon limit for a slowly varying T
    if upper > CAUSAL_TOLERANCE:  # a non-causal filter (a Q filter over the whole iteration): not triangular,
        rho = max(g for _l, _h, g in growth)  # so its diagonal blocks are not its eigenvalues
    return LiftedCheck(fmap.method, fmap.config.experiment.name, at, ts, n, width, use_full, rho, sigma, upper,
                       tuple(growth), tuple(float(d) for d in drift), first, time.perf_counter() - start, fmap.calls)


def measured_band_growth(config: Config, method: str, *, iterations: int, first: int, last: int,
                         bands: Sequence[float] = DEFAULT_BANDS, settled_from: float | None = None,
                         with_noise: bool = True) -> list[tuple[float, float, float]]:
    """(low, high, growth) per band, measured: a run of ``iterations`` iterations (with the experiment's
    disturbance and sensor noise, which excite every band as a power iteration's random start does, or
    noise-free); the band's energy of the memory's change m_{j+1} - m_j on the settled part, fitted as
    growth^j (least squares on its logarithm) over j = first .. last - 1. A diverged run is measured up
    to its last complete iteration."""
    from ilcforce.experiment import canonical, simulate_iterations
    from ilcforce.metrics import SETTLED_FROM

    settled = SETTLED_FROM if settled_from is None else settled_from
    config = config if with_noise else noise_free(config)
    config = dataclasses.replace(config, experiment=dataclasses.replace(config.experiment, iterations=iterations))
    n, ts = config.n_control, config.simulation.sample_time
    memories = []
    for record in simulate_iterations(config, canonical(method)):
        if record.status != STATUS_COMPLETE:
            break
        memories.append(np.concatenate([np.asarray(v, dtype=np.float64).reshape(n, -1)
                                        for v in record.memory.values()], axis=1))
    window = _settled_window(n, ts, settled)[:, None]
    changes = [memories[j + 1] - memories[j] for j in range(len(memories) - 1)]
    last = min(last, len(changes))
    if last - first < 3:
        raise AnalysisError(f"{method} completes only {len(memories)} iterations: too few to measure "
                            f"growth over j = {first}..{last}")
    out = []
    js = np.arange(first, last)
    for low, high, project in bands_of(bands, n, ts):
        energy = np.array([np.linalg.norm(window * project(changes[j])) for j in js])
        slope = np.polyfit(js, np.log(np.maximum(energy, 1e-300)), 1)[0]
        out.append((low, high, float(np.exp(slope))))
    return out
