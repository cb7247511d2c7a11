"""Plants behind one interface (``ilcforce.plants.base``): ``[plant] model`` picks one of :data:`MODELS`.

Each model is its own module, imported only when used, so numba loads only the kernels of the
robot a command runs. Nothing outside this package knows which robot it simulates: it asks
:func:`plant_class` for the class and uses the :class:`~ilcforce.plants.base.Plant` API and kernels.
"""

from __future__ import annotations

import importlib

from ilcforce.plants.base import Plant, PlantKernels, UnreachableError

#: the robot of an experiment that names none: the paper's five-bar
DEFAULT_MODEL = "fivebar"

#: model name -> (module, plant class, parameters class, default perturbed parameter)
MODELS = {
    "fivebar": ("ilcforce.plants.fivebar", "FiveBar", "FiveBarParams", "m3"),
    "serial2r": ("ilcforce.plants.serial2r", "Serial2R", "Serial2RParams", "m2"),
    # a 2-joint arm from a URDF or MJCF file ([plant.file_arm] path, end_effector; docs/model.md#model-file);
    # its default perturbation is the file's last link's mass (ModelFileParams.default_perturbed)
    "file_arm": ("ilcforce.plants.model_plant", "PlanarArm", "ModelFileParams", ""),
    # a 3-joint arm from a model file moving in space ([plant.spatial_arm] path, end_effector, g, posture;
    # docs/model.md#n-dof), run by the n-joint loop; its default perturbation is its last link's mass
    "spatial_arm": ("ilcforce.plants.spatial_plant", "SpatialArm", "SpatialArmParams", ""),
}


#: model name -> the robot's name in prose (tables, figure labels, the report's text)
TITLES = {"fivebar": "five-bar", "serial2r": "serial 2R arm", "file_arm": "arm from a model file",
          "spatial_arm": "spatial arm from a model file"}


def plant_title(model: str) -> str:
    """The robot ``model`` in words (``"five-bar"``), for text that must not name it in code."""
    if model not in MODELS:
        raise ValueError(f"plant.model must be one of {', '.join(MODELS)}, got {model!r}")
    return TITLES[model]


def _module(model: str):
    if model not in MODELS:
        raise ValueError(f"plant.model must be one of {', '.join(MODELS)}, got {model!r}")
    return importlib.import_module(MODELS[model][0])


def plant_class(model: str) -> type[Plant]:
    """The :class:`Plant` subclass of ``model``."""
    return getattr(_module(model), MODELS[model][1])


def params_class(model: str) -> type:
    """The parameters dataclass of ``model``."""
    return getattr(_module(model), MODELS[model][2])


def param_names(model: str) -> tuple[str, ...]:
    return _module(model).PARAM_NAMES


def perturbed_parameter(model: str) -> str:
    """The parameter ``model``'s perturbation changes unless the configuration names another
    (``plant.perturbation.parameter``): the five-bar's m3 (the paper's), the 2R arm's m2."""
    if model not in MODELS:
        raise ValueError(f"plant.model must be one of {', '.join(MODELS)}, got {model!r}")
    return MODELS[model][3]


def changed_parameter(config) -> str:
    """The parameter the true plant's change scales, read from a configuration in its TOML layout
    (a mapping, as a store keeps it): ``plant.perturbation.parameter``, else the model's own
    (:func:`perturbed_parameter`; the five-bar's when the configuration names no model)."""
    plant = config.get("plant", {}) if hasattr(config, "get") else {}
    plant = plant if hasattr(plant, "get") else {}
    change = plant.get("perturbation", {})
    parameter = change.get("parameter") if hasattr(change, "get") else None
    if parameter:
        return str(parameter)
    model = str(plant.get("model", DEFAULT_MODEL))
    model = model if model in MODELS else DEFAULT_MODEL
    if not perturbed_parameter(model):  # the robot's own default, read from its table (a model file's last link)
        try:
            return params_class(model)(**plant.get(model, {})).default_perturbed()
        except (TypeError, ValueError):
            return "(the last link's mass)"
    return perturbed_parameter(model)


def make_plant(params) -> Plant:
    """The plant object for a parameters instance of any model."""
    return plant_class(params.model)(params)


#: a robot from a URDF or MJCF file (docs/model.md#model-file), imported on first use: only reading
#: a file imports MuJoCo
_MODEL_FILE = {"load_model": "ilcforce.plants.model_file", "ModelFileError": "ilcforce.plants.model_file",
               "check_task_dimension": "ilcforce.plants.model_file", "shipped_models": "ilcforce.plants.model_file",
               "SerialArm": "ilcforce.plants.serial_arm"}


def __getattr__(name: str):
    if name in _MODEL_FILE:
        return getattr(importlib.import_module(_MODEL_FILE[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DEFAULT_MODEL", "MODELS", "TITLES", "plant_title", "Plant", "PlantKernels", "UnreachableError", "plant_class", "params_class",
           "param_names", "make_plant", "perturbed_parameter", "changed_parameter", *_MODEL_FILE]
