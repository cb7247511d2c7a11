"""What an adaptive law needs from the plant it controls, by the plant's code: the linear
parametrisation Dq(q) ddq_r + Cq(q, dq) dq_r + G_q(q) = Y(q, dq, dq_r, ddq_r) a (Slotine & Li 1987)
and dJ/dt, so that a compiled law (``ilcforce.controllers.sl_adapt``) calls one function whichever
robot it controls and names none.

The law calls three compiled functions, each branching on the plant's :func:`code` (its position in
``ilcforce.plants.MODELS``, carried in the law's packed gains): :func:`state_terms` (what the other two
read at the measured state, into the law's scratch), :func:`jacobian_rate_times` (dJ/dt x, n numbers, in
the coordinates of the plant's task) and :func:`regressor_rows` (Y, n rows of :func:`regressor_row_width`
(n) columns; the base parameters are the columns :func:`base_columns` names). Each plant keeps its own
form behind them:

* a 2-joint plant (the five-bar, the serial 2R arm, a planar arm from a model file) its closed form: its
  module provides its ``regressor`` (a compiled function returning Y, shape (2, 6), as a 12-tuple, row 0
  then row 1; a plant with fewer base parameters pads with zero columns), ``base_parameters(params)``,
  ``BASE_PARAMETER_NAMES`` (or ``base_parameter_names_of(params)``, for a robot read from a file) and
  ``BASE_PARAMETER_UNITS``; its base parameters are the regressor's first columns;
* an n-joint plant (the spatial arm) marks ``CHAIN_REGRESSOR``: its chain's whole regressor
  (``ilcforce.plants.chain_nd.slotine_li_regressor``, ten columns per link), of which the base columns
  are those the plant names (``base_columns_of``).
"""

from __future__ import annotations

import importlib

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.plants import MODELS, chain_nd, fivebar, planar_kernels, serial2r

__all__ = ["REGRESSOR_WIDTH", "PARAM_ROOM", "code", "base_parameter_names", "base_parameter_units",
           "base_parameters", "has_closed_form", "base_columns", "law_parameters", "work_width", "regressor_row_width",
           "state_terms", "jacobian_rate_times", "regressor_rows", "regressor", "jacobian_derivative"]

#: columns of a 2-joint plant's closed-form regressor tuple (the most base parameters of any such plant)
REGRESSOR_WIDTH = 6
#: room for a 2-joint plant's packed parameters in a law's gains (the most of any plant with a closed form),
#: so that its closed form may read past its own vector
PARAM_ROOM = max(getattr(m, "PACKED_LENGTH", len(m.PARAM_NAMES))
                 for m in (importlib.import_module(module) for module, *_ in MODELS.values()) if hasattr(m, "regressor"))

# the plants' codes (their positions in MODELS), constants of the compiled functions below
_FIVEBAR = float(list(MODELS).index("fivebar"))
_SERIAL2R = float(list(MODELS).index("serial2r"))
_FILE_ARM = float(list(MODELS).index("file_arm"))


def _module(model: str):
    if model not in MODELS:
        raise ValueError(f"no plant model {model!r}; expected one of {', '.join(MODELS)}")
    module = importlib.import_module(MODELS[model][0])
    if not (hasattr(module, "regressor") or hasattr(module, "CHAIN_REGRESSOR")):
        raise ValueError(f"sl-adapt needs the plant's regressor, which plant.model = {model!r} does not provide yet")
    return module


def code(model: str) -> float:
    """The plant's code in a law's packed gains: its position in ``MODELS``."""
    _module(model)
    return float(list(MODELS).index(model))


def base_parameter_names(model: str, params=None) -> tuple[str, ...]:
    """The base parameters' names (a plant read from a file names them from ``params``)."""
    module = _module(model)
    if hasattr(module, "base_parameter_names_of"):
        return tuple(module.base_parameter_names_of(params))
    return tuple(module.BASE_PARAMETER_NAMES)


def base_parameter_units(model: str) -> str:
    """The units of the base parameters, as words (e.g. ``"kg m^2"``)."""
    return _module(model).BASE_PARAMETER_UNITS


def base_parameters(params) -> np.ndarray:
    """The base parameters a of the plant with parameters ``params``, shape (n_base,)."""
    return _module(params.model).base_parameters(params)


def has_closed_form(model: str) -> bool:
    """Whether plant ``model`` gives its closed-form regressor (a 2-joint plant: its Gamma, as a planar task's
    ``sl-adapt.gamma``, has :data:`REGRESSOR_WIDTH` entries, one per column) rather than a chain's."""
    return not hasattr(_module(model), "CHAIN_REGRESSOR")


def base_columns(params) -> list[int]:
    """The columns of :func:`regressor_rows` that are the base parameters of the plant with parameters
    ``params``, in the base parameters' order (a closed form's first columns; a chain's own choice)."""
    module = _module(params.model)
    if has_closed_form(params.model):
        return list(range(len(module.base_parameters(params))))
    return list(module.base_columns_of(params))


def law_parameters(params) -> np.ndarray:
    """The nominal plant's parameters as the compiled functions below read them: a closed form's packed
    vector padded with zeros to :data:`PARAM_ROOM`, a chain's packed vector."""
    packed = np.asarray(params.as_array(), dtype=np.float64)
    if not has_closed_form(params.model):
        return packed
    out = np.zeros(max(PARAM_ROOM, packed.size))
    out[:packed.size] = packed
    return out


def work_width(model: str, n: int) -> int:
    """The scratch floats :func:`state_terms` and the two functions after it use for plant ``model`` of n joints."""
    return 0 if has_closed_form(model) else chain_nd.width(n)


def regressor_row_width(n: int) -> int:
    """The columns of each row :func:`regressor_rows` writes: a chain's ten inertial parameters per link (a
    closed form fills the first :data:`REGRESSOR_WIDTH`)."""
    return 10 * n


@njit(cache=True, error_model="numpy")
def state_terms(plant, p, q, dq, work):
    """What :func:`jacobian_rate_times` and :func:`regressor_rows` read at (q, dq), into ``work``: a chain's
    frames, P and J (``chain_nd.terms`` at level 0); nothing for a closed form."""
    if plant == _FIVEBAR or plant == _SERIAL2R or plant == _FILE_ARM:
        return
    chain_nd.terms(p, q, dq, 0, work)


@njit(cache=True, error_model="numpy")
def jacobian_rate_times(plant, p, q, dq, x, work, out, o):
    """dJ/dt x (n numbers, in the coordinates of the plant's task: a planar robot's plane, a spatial one's
    world) into out[o:o + n], at the state :func:`state_terms` was given."""
    if plant == _FIVEBAR or plant == _SERIAL2R or plant == _FILE_ARM:
        dJ00, dJ01, dJ10, dJ11 = jacobian_derivative(plant, p, q[0], q[1], dq[0], dq[1])
        out[o] = dJ00 * x[0] + dJ01 * x[1]
        out[o + 1] = dJ10 * x[0] + dJ11 * x[1]
        return
    c0, c1, c2 = chain_nd.jacobian_rate_times(p, dq, x, work)
    out[o] = c0
    out[o + 1] = c1
    out[o + 2] = c2


@njit(cache=True, error_model="numpy")
def regressor_rows(plant, p, q, dq, dq_r, ddq_r, work, Y, y0):
    """Y(q, dq, dq_r, ddq_r) (n rows of :func:`regressor_row_width` (n) columns, row-major, into Y[y0:]; Y a =
    Dq ddq_r + Cq(q, dq) dq_r + G_q on the base columns) at the state :func:`state_terms` was given: a closed
    form's (2, 6) in the first columns of its two rows, or a chain's whole regressor
    (``chain_nd.slotine_li_regressor``)."""
    if plant == _FIVEBAR or plant == _SERIAL2R or plant == _FILE_ARM:
        t = regressor(plant, p, q[0], q[1], dq[0], dq[1], dq_r[0], dq_r[1], ddq_r[0], ddq_r[1])
        row = 20  # regressor_row_width(2)
        for r in range(REGRESSOR_WIDTH):
            Y[y0 + r] = t[r]
            Y[y0 + row + r] = t[REGRESSOR_WIDTH + r]
        return
    chain_nd.slotine_li_regressor(p, dq, dq_r, ddq_r, work, Y, y0)


@njit(cache=True, error_model="numpy")
def jacobian_derivative(plant, p, th1, th2, d1, d2):
    """(dJ00, dJ01, dJ10, dJ11) of the 2-joint plant of code ``plant`` with packed parameters ``p``."""
    if plant == _FILE_ARM:
        return planar_kernels.jacobian_derivative(p, th1, th2, d1, d2)
    if plant == _SERIAL2R:
        dyn = serial2r._dynamics(p, th1, th2, d1, d2)
        return dyn[7], dyn[8], dyn[9], dyn[10]
    dyn5 = fivebar._dynamics(p, th1, th2, d1, d2)
    return dyn5[7], dyn5[8], dyn5[9], dyn5[10]


@njit(cache=True, error_model="numpy")
def regressor(plant, p, th1, th2, d1, d2, r1, r2, rr1, rr2):
    """Y(q, dq, dq_r, ddq_r) of the 2-joint plant of code ``plant``: (2, REGRESSOR_WIDTH) as a 12-tuple."""
    if plant == _FILE_ARM:
        return planar_kernels.regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2)
    if plant == _SERIAL2R:
        return serial2r.regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2)
    return fivebar.regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2)
