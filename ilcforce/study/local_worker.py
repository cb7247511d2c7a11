"""One worker of a study's local cluster, as a process of its own: Dask's nanny (it starts the worker
process, and starts it again when it dies or stops answering), with the driver's Dask settings,
ended when the driver is gone.

    python -P ilcforce/study/local_worker.py <scheduler address> <name> <driver's pipe> <settings, JSON>

It is run as a file, and imports nothing of ilcforce: a worker imports what its cells need when it
runs the first one.

:mod:`ilcforce.study.dask_run` starts one per worker, in a process group of its own (so a terminal's
Ctrl-C, which reaches the whole foreground group, is the driver's alone), with its output on
/dev/null. The driver holds the write end of a pipe whose read end this process watches: when the
driver ends, however it ends (kill -9 included), the read sees end of file and this process exits;
its worker process, Dask's child, exits with it (Dask's own watch of its parent).
"""

from __future__ import annotations

import json
import os
import sys
import threading


def _end_with_driver(fd: int) -> None:
    try:
        while os.read(fd, 1):
            pass
    except OSError:
        pass
    os._exit(0)


def main(argv: list[str]) -> None:
    address, name, fd, settings = argv[1], argv[2], int(argv[3]), json.loads(argv[4])
    threading.Thread(target=_end_with_driver, args=(fd,), name="ilcforce: driver watch", daemon=True).start()

    import asyncio
    import logging

    import dask
    from distributed import Nanny

    # set before the nanny is made: it reads its own settings (the worker's environment) when made,
    # and hands the worker process its configuration as it is then. The worker process is forked
    # from this one, which has imported Dask and nothing else: a spawned one imported Dask again,
    # and a 2-worker cluster took 3.4-4.5 s to start against 2.3-3.0 s forked (1.7-2.6 s with the
    # nannies inside the driver, as a LocalCluster runs them; 2 cores, load 6). Dask offers fork
    # (distributed.worker.multiprocessing-method); the nanny restarts a worker by forking again.
    dask.config.set({**settings, "distributed.worker.multiprocessing-method": "fork"})

    async def run() -> None:
        async with Nanny(address, nthreads=1, memory_limit=0, name=name, host="127.0.0.1", dashboard=False,
                         silence_logs=logging.CRITICAL) as nanny:
            await nanny.finished()

    asyncio.run(run())


if __name__ == "__main__":
    main(sys.argv)
