"""Compatibility shim: the five-bar moved to :mod:`ilcforce.plants.fivebar` (plant interface in
:mod:`ilcforce.plants`)."""

from ilcforce.plants.fivebar import (  # noqa: F401
    PARAM_NAMES, FiveBar, FiveBarParams, UnreachableError, _accel_terms, _dynamics, _inverse_kinematics,
    _kinematics, _task_model,
)

__all__ = ["FiveBarParams", "FiveBar", "UnreachableError", "PARAM_NAMES"]
