"""One control sample of the cross-check's controller side, compiled: steps 2 to 4 of ilcforce's n-joint loop
(``ilcforce.loop``, docs/model.md#n-dof) for a true state and contact force that another engine supplies.

Given the true joint angles and rates and the true contact force in the task frame, :func:`control_sample`
adds the sample's sensor noise, evaluates the NOMINAL plant's kernel at the measured state (position, J_X and,
if the law asks, the task-space model of eq. (4)), forms the "filtered" acceleration, force-rate and
force-acceleration estimates (docs/model.md#acceleration: first-order low-pass filtered differences; the
implicit scheme needs ilcforce's own plant and is not available here), fills the law's measurement vector in
the layout of ``ilcforce.controllers.nd`` and calls the law with ``write=True``. The sensing is the loop's own
code (``ilcforce.ndof.sensing``; tests/test_crosscheck.py holds the two measurement vectors equal on the same
states).
"""

from __future__ import annotations

import numpy as np

import functools

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import njit
from ilcforce.ndof.sensing import filtered_estimates, measure, sense_force, sense_joints

#: control_sample's outcomes
SAMPLE_OK, SAMPLE_WORKING_MODE = 0, 1


def filter_width(n: int) -> int:
    """The filters' state: previous dX, previous F, acceleration, dF, ddF (n each)."""
    return 5 * n


@njit(cache=True, error_model="numpy", inline="always")
def _control_sample(law, dyn_nom, p_nom, wall, gains, mem_prev, mem_new, ref, noise, ts, beta, nominal_dyn,
                   filters, k, th, d, fa, force, meas, diag, out_n, tau, qm, dqm, fmeas):
    """The torque of control sample k into ``tau``; SAMPLE_OK, or SAMPLE_WORKING_MODE when the nominal model
    finds the measured pose outside its working mode (as the loop's step 2)."""
    n = th.shape[0]
    nn = n * n
    t = k * ts
    Xs = np.empty(n)
    JXs = np.empty(nn)
    dJvs = np.empty(n)
    DJ = np.empty(nn)
    LU = np.empty(nn)
    piv = np.empty(n)
    Ji = np.empty(nn)
    tmp = np.empty(nn)
    col = np.empty(n)
    # 2. sensors, then the nominal model at the measured state
    sense_joints(n, k, th, d, noise, qm, dqm)
    sense_force(n, k, fa, force, noise, fmeas)  # the normal component, as the loop's sensor
    if not measure(n, dyn_nom, p_nom, wall, qm, dqm, fmeas, 2 if nominal_dyn != 0 else 0, out_n, Xs, JXs, dJvs, DJ,
                   LU, piv, col, Ji, tmp, meas):
        return SAMPLE_WORKING_MODE
    # 3. the filtered estimates (docs/model.md#acceleration)
    filtered_estimates(n, k, ts, beta, meas, fmeas, filters, 0)
    # 4. the law, writing its memory
    law(k, t, meas, ref, gains, mem_prev, mem_new, True, diag, tau)
    return SAMPLE_OK



@functools.lru_cache(maxsize=16)
def control_sample(law, dyn_nom):
    """The compiled ``control_sample(p_nom, wall, gains, mem_prev, mem_new, ref, noise, ts, beta, nominal_dyn,
    filters, k, th, d, fa, force, meas, diag, out_n, tau, qm, dqm, fmeas) -> SAMPLE_OK or SAMPLE_WORKING_MODE``
    of the law ``law`` (a method's compiled ``law``) and the nominal plant's kernel ``dyn_nom``; arrays are
    float64 and contiguous: wall (``ilcforce.task.Wall.packed``: y_e, K_e, w, R, D_e, mu, v_eps), the loop's gains, memory (n_control, width) and
    reference (n_control, 6 n), the sensor noise (n_control, 3 n), the filters (:func:`filter_width`), the
    state, the force axis fa (the wall's normal) and the contact force in the task frame (n each, rad, rad/s, N; the
    sensor reads its component fa), and the outputs: meas, diag (sigma,
    then the law's scratch), the kernel's buffer, tau (N m), the measured angles, rates and force.

    The law and the kernel are compiled into it as constants: passing them as first-class function
    arguments, as the loop does once per chunk, costs numba a look-up of their addresses on every call,
    which here is every control sample (about 0.4 ms, 20 times the rest of the sample). Made once per
    (law, plant kernel) pair in a process; numba compiles it in a few seconds."""

    def run(p_nom, wall, gains, mem_prev, mem_new, ref, noise, ts, beta, nominal_dyn, filters, k, th, d, fa, force,
            meas, diag, out_n, tau, qm, dqm, fmeas):
        return _control_sample(law, dyn_nom, p_nom, wall, gains, mem_prev, mem_new, ref, noise, ts, beta,
                               nominal_dyn, filters, k, th, d, fa, force, meas, diag, out_n, tau, qm, dqm, fmeas)

    return _jit.numba().njit(error_model="numpy")(run)
