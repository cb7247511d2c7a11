"""``python -m ilcforce.controllers``: the registered method names, space-separated (for the Makefile)."""

from ilcforce.controllers import method_names

print(" ".join(method_names()))
