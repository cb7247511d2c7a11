"""The unit of every configuration key (``section.key`` as ``--set`` and the TOML files spell it).

Tables and figures that show a configuration value (a study's swept key in the tidy metrics and on a
sweep figure's x-axis) take its unit from :func:`config_unit`. The units of the sections below are
listed here; each method's gains carry their own (``<GainsClass>.units``), so a new method brings
its units with it. Conventions, the same as the stores': SI units as text (``"m"``, ``"N s/m"``),
``"1"`` for a dimensionless number, ``""`` for a text value (a name, a switch).
"""

from __future__ import annotations

#: The unit of each key of the non-method sections (the plant's link parameters: :data:`_LINK_UNITS`).
SECTION_UNITS: dict[str, str] = {
    "experiment.name": "", "experiment.description": "", "experiment.seed": "1", "experiment.iterations": "1",
    "plant.model": "",
    "tuning.source": "", "tuning.withheld": "", "tuning.methods": "", "tuning.cap_reference": "", "tuning.cap": "N",
    "plant.perturbation.parameter": "", "plant.perturbation.factor": "1",
    "plant.perturbation.from_iteration": "1",
    "wall.position": "m", "wall.stiffness": "N/m", "wall.force_sign": "",
    "wall.damping": "N s/m", "wall.friction": "1", "wall.friction_velocity": "m/s",
    "wall.normal": "1", "wall.tangent": "1",  # directions (normalised)
    "reference.duration": "s", "reference.x_amplitude": "m", "reference.x_offset": "m",
    "reference.x_frequency": "Hz", "reference.force_sine_amplitude": "N", "reference.force_sine_frequency": "Hz",
    "reference.force_exp_amplitude": "N",
    "reference.v_amplitude": "m", "reference.v_offset": "m", "reference.v_frequency": "Hz",
    "simulation.sample_time": "s", "simulation.substeps": "1", "simulation.log_every": "1",
    "simulation.acceleration": "", "simulation.filter_hz": "Hz", "simulation.torque_bound": "N m",
    "simulation.initial_position": "m", "simulation.initial_velocity": "", "simulation.implicit_fallback": "",
    "noise.disturbance_amplitude": "N", "noise.disturbance_min_frequency": "Hz",
    "noise.disturbance_max_frequency": "Hz", "noise.encoder": "rad", "noise.joint_rate": "rad/s",
    "noise.force_sensor": "N", "noise.scale": "1",
    "surface.selection": "1", "surface.lambda_p": "1/s", "surface.lambda_f1": "m/(N s)", "surface.lambda_f2": "m/N",
}

#: A robot's link parameters by the first letters of their names (``plant.<model>.<name>``):
#: lengths L1, Lc1 ... in m, masses m1 ... in kg, inertias I1 ... in kg m^2, gravity g in m/s^2.
_LINK_UNITS = (("Lc", "m"), ("L", "m"), ("m", "kg"), ("I", "kg m^2"), ("g", "m/s^2"))


def config_unit(key: str) -> str:
    """The unit of configuration key ``key`` (e.g. ``"simulation.sample_time"`` -> ``"s"``,
    ``"c3.eta"`` -> ``"N s/m"``); KeyError for a key the configuration does not have."""
    if key in SECTION_UNITS:
        return SECTION_UNITS[key]
    section, _, name = key.rpartition(".")
    if section.startswith("plant.") and section.count(".") == 1:
        from ilcforce.plants import MODELS, param_names, params_class

        model = section.split(".")[1]
        own = getattr(params_class(model), "units", {}) if model in MODELS else {}
        if name in own:  # a robot whose parameters say their units (a model file's: path, ..., g)
            return own[name]
        if model in MODELS and name in param_names(model):
            for prefix, unit in _LINK_UNITS:
                if name.startswith(prefix):
                    return unit
    from ilcforce.controllers import REGISTRY

    if section in REGISTRY:
        units = getattr(REGISTRY[section].gains_class, "units", {})
        if name in units:
            return units[name]
    raise KeyError(f"no unit for configuration key {key!r}")


def axis_label(key: str) -> str:
    """``key`` with its unit for an axis or a column header: ``"simulation.sample_time (s)"``; the key
    alone when it has no unit or is dimensionless (or unknown)."""
    try:
        unit = config_unit(key)
    except KeyError:
        return key
    return f"{key} ({unit})" if unit not in ("", "1") else key
