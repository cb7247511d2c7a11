"""The tools that keep a learning law bounded over long runs, shared by ``c2-robust`` and ``c3-robust``.

Why they are needed is shown in docs/model.md#long-run: under the paper's setup the learned memories of
C2 and C3 grow without bound, by two separate mechanisms, and each tool answers one.

* **The start mismatch.** Every iteration starts at rest while the reference asks for a moving force,
  so sigma at the first samples is the same nonzero value in every iteration. No feed-forward can remove
  an error in the initial state, so a law that learns from it adds the same amount at those samples in
  every iteration (the t = 0 memory grows linearly) until the start kick destabilises the run (noise-free
  C3 diverges at j = 99, 30 ms into the iteration). Remedy: a **learning window** that opens at
  ``learn_from`` (s): the memory is not updated before it (ILC's identical-initialisation condition holds
  from there on); the law's feedback acts there as everywhere.
* **Noise and disturbance integrated into the memory.** Each iteration adds what the sensor noise and the
  non-repetitive disturbance put into sigma; at high frequencies, where the sampled current-iteration
  learning loop does not contract, that content grows geometrically from iteration to iteration (about
  3-4% per iteration under the paper's noise) until the run diverges mid-trajectory. Remedy: a
  **zero-phase Q filter** on the learned memory after each iteration (a Butterworth low-pass run forwards
  and backwards, ``scipy.signal.sosfiltfilt``; Bristow, Tharayil & Alleyne, IEEE CSM 26(3), 2006, eq. 13)
  that removes the content the learning cannot follow.

With ``learn_from = 0`` and ``q_cutoff = 0`` each robust law is its plain law exactly (the tests pin it).
Both tools are needed: the window alone leaves a step in the learned feed-forward at ``learn_from`` that
the unfiltered learning amplifies; the Q filter alone leaves the start drift (docs/model.md#long-run).
"""

from __future__ import annotations

import math

import numpy as np



def check_robust_gains(section: str, learn_from: float, q_cutoff: float, q_order: int) -> None:
    """The robustness options, or ValueError naming the bad key (one line)."""
    if not (math.isfinite(learn_from) and learn_from >= 0):
        raise ValueError(f"{section}.learn_from must be a finite time >= 0 s, got {learn_from!r}")
    if not (math.isfinite(q_cutoff) and q_cutoff >= 0):
        raise ValueError(f"{section}.q_cutoff must be a frequency >= 0 Hz (0: no Q filter), got {q_cutoff!r}")
    if isinstance(q_order, bool) or not (isinstance(q_order, (int, np.integer)) or float(q_order).is_integer()) \
            or not (1 <= int(q_order) <= 8):
        raise ValueError(f"{section}.q_order must be an integer 1..8, got {q_order!r}")


class QFilter:
    """A zero-phase Butterworth low-pass Q applied to a learned memory along time (axis 0).

    ``cutoff`` (Hz) 0 means no filter (the memory passes unchanged). Shapes: ``apply`` takes and
    returns an (n_control, width) array."""

    def __init__(self, section: str, cutoff: float, order: int, sample_time: float):
        self.sos = None
        if cutoff == 0:
            return
        if not (math.isfinite(sample_time) and sample_time > 0):
            raise ValueError(f"{section} needs the control sample time to design its Q filter")
        nyquist = 0.5 / sample_time
        if cutoff >= nyquist:
            raise ValueError(f"{section}.q_cutoff ({cutoff:g} Hz) must be below the Nyquist frequency "
                             f"{nyquist:g} Hz of the control sample time")
        from scipy.signal import butter  # here, not at import: the registry imports every method module

        self.sos = butter(int(order), cutoff, fs=1.0 / sample_time, output="sos")

    def apply(self, memory: np.ndarray) -> np.ndarray:
        if self.sos is None:
            return memory
        from scipy.signal import sosfiltfilt

        # Bristow et al. (2006) eq. 13, zero phase; C order, as the compiled loop takes its memory
        return np.ascontiguousarray(sosfiltfilt(self.sos, memory, axis=0))


class QFiltered:
    """For a :class:`~ilcforce.controllers.base.MemoryController` whose gains carry ``q_cutoff`` and
    ``q_order``: the memory a finished iteration wrote passes through Q before iteration j + 1 reads it
    (a diverged iteration hands on nothing, as in the base class). Put it first among the bases."""

    def __init__(self, n_control: int, surface, wall_sign: float, gains, **options):
        super().__init__(n_control, surface, wall_sign, gains, **options)
        self._q = QFilter(gains.section, gains.q_cutoff, gains.q_order, self.sample_time)

    def end_iteration(self, record) -> None:
        """The finished iteration's memory through Q (zero phase), then kept for iteration j + 1."""
        if not record.diverged:
            self._new = self._q.apply(self._new)
        super().end_iteration(record)
