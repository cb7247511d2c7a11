"""What an adaptive law needs from the plant it controls, by the plant's code: the linear
parametrisation Dq(q) ddq_r + Cq(q, dq) dq_r + G_q(q) = Y(q, dq, dq_r, ddq_r) a (Slotine & Li 1987)
and dJ/dt, so that a compiled law (``ilcforce.controllers.sl_adapt``) calls one function whichever
robot it controls and names none.

A 2-joint plant module provides its ``regressor`` (a compiled function returning Y, shape (2, 6), as a
12-tuple, row 0 then row 1; a plant with fewer base parameters pads with zero columns),
``base_parameters(params)``, ``BASE_PARAMETER_NAMES`` (or ``base_parameter_names_of(params)``, for a
robot read from a file) and ``BASE_PARAMETER_UNITS``. A law's packed
gains carry the plant's :func:`code` (its position in ``ilcforce.plants.MODELS``); the compiled
functions below branch on it.

An n-joint plant (the spatial arm) instead marks ``CHAIN_REGRESSOR``: the n-axis law computes its chain's whole
regressor (``ilcforce.plants.chain_nd.slotine_li_regressor``, ten columns per link) through the ``nd_*``
functions here and keeps the base columns the plant names (``base_columns_of``).
"""

from __future__ import annotations

import importlib

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.plants import MODELS, chain_nd, fivebar, planar_kernels, serial2r

__all__ = ["REGRESSOR_WIDTH", "PARAM_ROOM", "code", "base_parameter_names", "base_parameter_units",
           "base_parameters", "regressor", "jacobian_derivative", "has_chain_regressor", "base_columns", "nd_frames",
           "nd_jacobian_rate_times", "nd_regressor", "nd_work_width"]

#: columns of every plant's regressor tuple (the most base parameters of any plant)
REGRESSOR_WIDTH = 6
#: room for any plant's packed parameters in a law's gains (the most of any plant that has a regressor)
PARAM_ROOM = max(getattr(m, "PACKED_LENGTH", len(m.PARAM_NAMES))
                 for m in (importlib.import_module(module) for module, *_ in MODELS.values()) if hasattr(m, "regressor"))


# --- the n-axis law's: an n-joint plant's regressor is its chain's (ilcforce.plants.chain_nd) ---------------

def has_chain_regressor(model: str) -> bool:
    """Whether plant ``model`` gives the n-axis adaptive law its chain's regressor (a plant of n joints)."""
    return hasattr(_module(model), "CHAIN_REGRESSOR")


def base_columns(params) -> list[int]:
    """The chain regressor's columns that are the base parameters of the plant with parameters ``params``."""
    return list(_module(params.model).base_columns_of(params))


def nd_work_width(n: int) -> int:
    """The scratch floats :func:`nd_frames` and the two functions after it use for an n-joint chain."""
    return chain_nd.width(n)


@njit(cache=True, error_model="numpy")
def nd_frames(p, q, dq, work):
    """The frames, P and J of the chain ``p`` at (q, dq) into ``work`` (``chain_nd.terms`` at level 0), which
    :func:`nd_jacobian_rate_times` and :func:`nd_regressor` read."""
    chain_nd.terms(p, q, dq, 0, work)


@njit(cache=True, error_model="numpy")
def nd_jacobian_rate_times(p, dq, x, work):
    """dJ/dt x (world frame, 3 numbers) of the chain ``p`` at the state :func:`nd_frames` was given."""
    return chain_nd.jacobian_rate_times(p, dq, x, work)


@njit(cache=True, error_model="numpy")
def nd_regressor(p, dq, dq_r, ddq_r, work, Y, y0):
    """The chain's whole Y(q, dq, dq_r, ddq_r) (n x 10 n, row-major, into Y[y0:]; Y pi = M ddq_r + C(q, dq) dq_r
    + g) at the state :func:`nd_frames` was given (``chain_nd.slotine_li_regressor``)."""
    chain_nd.slotine_li_regressor(p, dq, dq_r, ddq_r, work, Y, y0)


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


@njit(cache=True, error_model="numpy")
def jacobian_derivative(plant, p, th1, th2, d1, d2):
    """(dJ00, dJ01, dJ10, dJ11) of the plant of code ``plant`` with packed parameters ``p``."""
    if plant > 1.5:
        return planar_kernels.jacobian_derivative(p, th1, th2, d1, d2)
    if plant > 0.5:
        dyn = serial2r._dynamics(p, th1, th2, d1, d2)
        return dyn[7], dyn[8], dyn[9], dyn[10]
    dyn5 = fivebar._dynamics(p, th1, th2, d1, d2)
    return dyn5[7], dyn5[8], dyn5[9], dyn5[10]


@njit(cache=True, error_model="numpy")
def regressor(plant, p, th1, th2, d1, d2, r1, r2, rr1, rr2):
    """Y(q, dq, dq_r, ddq_r) of the plant of code ``plant``: (2, REGRESSOR_WIDTH) as a 12-tuple."""
    if plant > 1.5:
        return planar_kernels.regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2)
    if plant > 0.5:
        return serial2r.regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2)
    return fivebar.regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2)
