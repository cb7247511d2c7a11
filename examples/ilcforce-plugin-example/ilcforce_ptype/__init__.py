"""An ilcforce plugin method: P-type ILC with proportional feedback (docs/plugins.md).

ilcforce reads :data:`METHOD_SPEC` through the entry point ``p-ilc`` of the group ``ilcforce.methods``
(pyproject.toml). This module is imported when ilcforce first looks into its method registry, so it
stays light: the law lives in :mod:`ilcforce_ptype.law`, which imports no numba either (ilcforce
compiles a law only when a run uses it).
"""

from ilcforce.controllers import MethodSpec

METHOD_SPEC = MethodSpec(
    name="p-ilc",  # --method value and the TOML section of its gains ([p-ilc])
    title="P-ILC: P-type ILC on the sliding surface with proportional feedback (a plugin)",
    label="P-ILC",  # legends and table columns
    color="#6A3D9A",  # any matplotlib colour
    module="ilcforce_ptype.law",
    controller="PTypeController",
    gains="PTypeGains",
    learns="within",  # the memory of iteration j is written while j runs, from j - 1's (ilcforce.controllers.LEARNS)
    carries_memory=True,
    in_paper=False,  # plugins never are
    reference="Arimoto, Kawamura & Miyazaki (1984), P-type learning on the sliding surface of eq. (8)",
)
