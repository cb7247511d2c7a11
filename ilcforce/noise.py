"""Non-repetitive disturbance and bounded sensor noise (docs/model.md#noise).

Every draw comes from a ``numpy.random.Generator`` derived from (seed, iteration) only, so every
method in an experiment sees the same disturbance and noise (common random numbers), a rerun is
bit-identical, and a resumed run draws exactly what an uninterrupted one would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_DISTURBANCE_STREAM = 0
_NOISE_STREAM = 1

#: Columns of the per-sample noise array: encoder (2), joint rate (2), force sensor (x, y).
NOISE_WIDTH = 6


@dataclass(frozen=True)
class NoiseModel:
    """Scales of the disturbance and of the uniform, bounded sensor noise. 0 turns a source off.

    ``scale`` multiplies every source at once (the disturbance's amplitude and the encoder, joint-rate
    and force-sensor bounds; not the disturbance's frequencies): the paper gives no noise levels, so
    one factor moves the whole noise level while keeping the sources' proportions (docs/model.md#noise).
    """

    disturbance_amplitude: float = 0.02  # |F_v| per axis, N (must stay below C1's alpha = 0.1 N)
    disturbance_min_frequency: float = 0.5  # Hz
    disturbance_max_frequency: float = 5.0  # Hz
    encoder: float = 1e-6  # joint angle noise bound, rad
    joint_rate: float = 1e-4  # joint rate noise bound, rad/s
    force_sensor: float = 0.01  # force noise bound on each axis, N
    scale: float = 1.0  # one factor on every source above (1: as listed; 0: no disturbance, no noise)

    def __post_init__(self) -> None:
        for name in ("disturbance_amplitude", "encoder", "joint_rate", "force_sensor", "scale",
                     "disturbance_min_frequency", "disturbance_max_frequency"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"noise.{name} must be finite and >= 0, got {v!r}")
        if self.disturbance_min_frequency > self.disturbance_max_frequency:
            raise ValueError("noise.disturbance_min_frequency must not exceed noise.disturbance_max_frequency")


@dataclass(frozen=True)
class IterationDraws:
    """The random inputs of one iteration.

    Attributes
    ----------
    frequency : ndarray, shape (2,)
        Disturbance frequencies (f1, f2) for the x and y axes, Hz.
    phase : ndarray, shape (2,)
        Disturbance phases (p1, p2), rad.
    sensor : ndarray, shape (n_control, 6)
        Additive sensor noise per control sample: encoder (rad), joint rate (rad/s), force (N).
    """

    frequency: np.ndarray
    phase: np.ndarray
    sensor: np.ndarray


def draw_iteration(seed: int, iteration: int, n_control: int, model: NoiseModel, n: int = 2) -> IterationDraws:
    """Draw the disturbance parameters and sensor noise of iteration ``iteration`` for a task of ``n`` axes
    and n joints (n = 2: the draws of every 2-D experiment; otherwise the same laws, n wide)."""
    rng_d = np.random.default_rng([seed, iteration, _DISTURBANCE_STREAM])
    frequency = rng_d.uniform(model.disturbance_min_frequency, model.disturbance_max_frequency, size=n)
    phase = rng_d.uniform(0.0, 2.0 * math.pi, size=n)
    rng_n = np.random.default_rng([seed, iteration, _NOISE_STREAM])
    unit = rng_n.uniform(-1.0, 1.0, size=(n_control, 3 * n))  # NOISE_WIDTH for n = 2
    bounds = np.repeat([model.encoder, model.joint_rate, model.force_sensor], n) * model.scale
    return IterationDraws(frequency=frequency, phase=phase, sensor=unit * bounds)


def disturbance(t: np.ndarray, draws: IterationDraws, model: NoiseModel) -> np.ndarray:
    """F_v(t) = s A [sin(2 pi f1 t + p1), sin(2 pi f2 t + p2)] (N), shape (n, 2) for t of shape (n,);
    s = ``model.scale``. Its norm is bounded by sqrt(2) s A: the bound eq. (2) states (by the norm)."""
    t = np.asarray(t, dtype=np.float64)[:, None]
    return model.disturbance_amplitude * model.scale * np.sin(2.0 * math.pi * draws.frequency[None, :] * t + draws.phase[None, :])
