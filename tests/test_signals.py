"""Ctrl-C and SIGTERM wherever they land: one line naming the signal, exit 130 or 143, no traceback.

The mid-run stops of each command are tested beside the command (test_robustness, test_compare_parallel,
test_study_faults); here: the entry point's own handling, for a signal that lands outside a command's
(while typer parses, while a command imports) or whose KeyboardInterrupt Python dropped.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from ilcforce import stops


def _main_with(app_body: str) -> subprocess.CompletedProcess:
    """Run ilcforce.cli.main.main() in a fresh process with its typer app replaced by ``app_body``."""
    code = ("import os, signal, time\n"
            "from ilcforce import stops\nfrom ilcforce.cli import main as cli\n"
            f"def app(**kwargs):\n    {app_body}\n"
            "cli.app = app\n"
            "cli.main()\n")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_signal_outside_any_command_is_one_line(sig, code, word):
    done = _main_with(f"os.kill(os.getpid(), {int(sig)}); time.sleep(10)")
    assert done.returncode == code, done.stderr
    assert done.stderr.strip().splitlines() == [f"{word}: stopped before the command finished"]


def test_a_dropped_sigterm_still_ends_in_143_with_one_line():
    """Python drops a KeyboardInterrupt raised inside a GC or weakref callback; the command then
    finishes, and the entry point still reports the SIGTERM (a batch system's stop)."""
    done = _main_with("stops.note(signal.SIGTERM)")
    assert done.returncode == 143, done.stderr
    assert done.stderr.strip().splitlines() == ["terminated (SIGTERM): the command had finished"]


def test_an_error_in_a_destructor_after_a_stop_signal_prints_nothing():
    """An interrupt can leave an object half-built (seen: llvmlite's ObjectRef), whose destructor
    then fails; once a stop signal came, that is not shown (the process is ending)."""
    body = ("stops.note(signal.SIGTERM)\n"
            "    class Half:\n"
            "        def __del__(self):\n"
            "            raise AttributeError('half built')\n"
            "    Half()\n"
            "    raise KeyboardInterrupt")
    done = _main_with(body)
    assert done.returncode == 143, done.stderr
    assert done.stderr.strip().splitlines() == ["terminated (SIGTERM): stopped before the command finished"]


def test_simulate_stops_at_once_on_a_signal_whose_interrupt_was_dropped():
    from ilcforce.cli.run import deferred_interrupt

    stops.STOPS.clear()
    with deferred_interrupt() as stop_requested:
        assert not stop_requested()
    stops.note(signal.SIGTERM)
    try:
        with deferred_interrupt() as stop_requested:
            assert stop_requested()
    finally:
        stops.STOPS.clear()


@pytest.mark.parametrize("delay", [0.15, 0.3, 0.45, 0.6])
def test_sigterm_early_in_simulate_is_one_line_and_143(tmp_path, delay):
    """Early, the signal lands in the imports, in typer's parsing or in the command's set-up (it used
    to give exit 130 and no line). Before the entry point runs, Python's default action ends the
    process silently (-15); anything else must be one line and 143."""
    proc = subprocess.Popen([sys.executable, "-m", "ilcforce", "simulate", "-m", "c3", "-n", "30",
                             "--results", str(tmp_path)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    time.sleep(delay)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    if proc.returncode == -signal.SIGTERM:
        assert stderr == ""
        return
    assert proc.returncode == 143, stderr
    assert "Traceback" not in stderr and "Exception ignored" not in stderr, stderr
    assert stderr.strip().splitlines()[-1].startswith("terminated (SIGTERM): "), stderr


@pytest.mark.parametrize("sig, code, word", [(signal.SIGINT, 130, "interrupted"),
                                             (signal.SIGTERM, 143, "terminated (SIGTERM)")])
def test_a_signal_while_the_command_is_still_importing_is_one_line(sig, code, word):
    """In the first tenth of a second the entry point is still importing typer and the CLI; a Ctrl-C
    there raised KeyboardInterrupt inside an import, a traceback (found by an attack on the CLI).
    The entry point's first module (ilcforce/cli/entry.py) answers stop signals from its first line."""
    child = ("import os, signal, time\nimport ilcforce.cli.entry, ilcforce.cli.main\n"
             "ilcforce.cli.main.main = lambda: (os.kill(os.getpid(), %d), time.sleep(10))\n"  # mid-import stand-in
             "ilcforce.cli.entry.main()\n" % int(sig))
    done = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=60)
    assert done.returncode == code, done.stderr
    assert done.stderr.strip().splitlines() == [f"{word}: stopped before the command started"]


def test_both_entry_points_start_with_the_early_signal_handling():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    assert 'ilcforce = "ilcforce.cli.entry:main"' in (root / "pyproject.toml").read_text(encoding="utf-8")
    assert (root / "ilcforce" / "__main__.py").read_text(encoding="utf-8").startswith("from ilcforce.cli.entry import")
