"""Controller registry: ``--method`` names to controller classes and their gain dataclasses.

Adding a method is one new module implementing :class:`~ilcforce.controllers.base.Controller`
and one line here.
"""

from ilcforce.controllers.base import Controller
from ilcforce.controllers.c1 import C1Controller, C1Gains
from ilcforce.controllers.c2 import C2Controller, C2Gains
from ilcforce.controllers.c3 import C3Controller, C3Gains

#: method name -> (controller class, gains dataclass)
REGISTRY = {
    "c1": (C1Controller, C1Gains),
    "c2": (C2Controller, C2Gains),
    "c3": (C3Controller, C3Gains),
}

__all__ = ["REGISTRY", "Controller", "C1Gains", "C2Gains", "C3Gains"]
