"""ilcforce: iterative learning control experiments for hybrid force/position control."""

__version__ = "0.1.0"


def open(path):  # noqa: A001 - ilcforce.open reads a store, as the README shows
    """Open a stored run: ``ilcforce.open("results/paper/c3.h5")`` -> :class:`ilcforce.store.run.Run`
    with ``.metrics``, ``.iteration(j)`` (``j = -1``: the last), ``.memory(j)``, ``.config`` (gains as
    ``.config.c3``); ``len(run)`` iterations, ``run[j]``, and ``for record in run``."""
    from ilcforce.store.run import open_run

    return open_run(path)
