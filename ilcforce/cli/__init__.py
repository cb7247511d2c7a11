"""The command line (``ilcforce``, ``python -m ilcforce``): parse, call one library function, render.

:mod:`~ilcforce.cli.entry` is the console entry point (stop signals answered from the first moment),
:mod:`~ilcforce.cli.main` assembles the Typer app from the command modules (:mod:`~ilcforce.cli.run`:
simulate and compare; :mod:`~ilcforce.cli.study`: study and export; :mod:`~ilcforce.cli.report`:
report, validate, version; :mod:`~ilcforce.cli.config`), which share :mod:`~ilcforce.cli.base`.
Nothing in the library imports this package.
"""
