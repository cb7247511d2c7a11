"""Writers protected per file, not per name; clean-up that removes only what a writer made.

Found by attacks: resuming through a symbolic link while another command overwrote the target
made one store of two runs that passed `validate`; a writer's clean-up deleted a live store named
`<store>.tmp` by its name pattern; a refused `--overwrite` onto a dangling link left `<out>.lock`;
a kill -9 while a study store was being made left `.<name>.h5.tmp-PID` that no rerun removed.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ilcforce import store
from ilcforce.cli.main import app
from ilcforce.store import StoreError, StoreLockedError

from storekit import make_record, path, resumed_config, write_run, writer  # noqa: F401 - path is a fixture
from test_study import small_study


def test_two_names_of_one_file_are_one_writer(path):
    """A writer through a symbolic link and one through the real name: the second is refused while
    the first runs, so no store mixes two runs."""
    write_run(path, 1, finish=None)
    link = path.parent.parent / "link.h5"
    link.symlink_to(path)
    with writer(path, config=resumed_config(3), resume=True) as first:
        first.append(make_record(1))
        for name in (link, Path(str(path.parent) + "/../paper/c3.h5")):
            with pytest.raises(StoreLockedError):
                with writer(name, overwrite=True):
                    pass
        with pytest.raises(StoreLockedError):  # two resumes through two names: duplicate /metrics rows
            with writer(link, config=resumed_config(3), resume=True):
                pass
        assert store.writer_active(link), "a reader through the link sees the writer"
        first.append(make_record(2))
        first.finish("complete")
    store.validate(path)
    assert store.iterations(path) == [0, 1, 2]


def test_a_live_store_named_like_an_old_temporary_copy_is_left_alone(tmp_path):
    """`c1.h5.tmp` is a store of its own, written while `c1.h5`'s writer commits and cleans up."""
    folder = tmp_path / "results" / "paper"
    plain, other = folder / "c1.h5", folder / "c1.h5.tmp"
    with writer(other, config=resumed_config(2)) as second:
        second.append(make_record(0))
        with writer(plain) as first:
            for j in range(3):
                first.append(make_record(j))
            first.finish("complete")
        with writer(plain, resume=True, config=resumed_config(3)):
            pass
        second.append(make_record(1))
        second.finish("complete")
    assert store.iterations(other) == [0, 1] and store.iterations(plain) == [0, 1, 2]
    store.validate(other)


def test_a_temporary_name_is_not_a_store_name(tmp_path):
    """A store may not take the name ilcforce gives its temporary copies (they are removed once their
    process is gone)."""
    with pytest.raises(StoreError, match="temporary copies"):
        with writer(tmp_path / f".c1.h5.tmp-{os.getpid() + 1}"):
            pass


def test_a_refused_overwrite_onto_a_dangling_link_leaves_nothing(tmp_path):
    """The refusal comes before any lock file is made beside the link (or its missing target)."""
    folder = tmp_path / "results" / "paper"
    folder.mkdir(parents=True)
    link = folder / "c3.h5"
    link.symlink_to(tmp_path / "gone.h5")
    before = sorted(os.listdir(folder))
    result = CliRunner().invoke(app, ["simulate", "--method", "c3", "--iters", "1", "--out", str(link),
                                      "--overwrite"])
    assert result.exit_code == 2 and "symbolic link to a missing file" in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1
    assert sorted(os.listdir(folder)) == before and not (tmp_path / "gone.h5.lock").exists()


def test_a_study_driver_killed_while_making_its_store_leaves_nothing_a_rerun_keeps(tmp_path):
    """kill -9 of a driver inside the creation of its study store (stopped right after opening its
    temporary file): the rerun removes `.tiny.h5.tmp-PID` and completes."""
    results = tmp_path / "r"
    script = (
        "import os, signal, sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from ilcforce.store import commit\n"
        "from ilcforce.study import run_study\n"
        "from test_study import small_study\n"
        "real = commit._open_tmp\n"
        "def stop(tmp):\n"
        "    fd = real(tmp)\n"
        "    print('made', flush=True); os.kill(os.getpid(), signal.SIGSTOP)\n"
        "    return fd\n"
        "commit._open_tmp = stop\n"
        f"run_study(small_study(seeds='0-0', methods=('c1',)), {str(results)!r}, workers=1)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        assert child.stdout.readline().strip() == "made"
        leftover = results / "studies" / f".tiny.h5.tmp-{child.pid}"
        assert leftover.exists()
    finally:
        child.kill()
        child.wait(timeout=30)
        child.stdout.close()
    from ilcforce.study import run_study

    summary = run_study(small_study(seeds="0-0", methods=("c1",)), results, workers=1)
    assert summary.ran == 1 and not leftover.exists()
    assert sorted(p.name for p in (results / "studies").iterdir()) == ["tiny.h5", "tiny.h5.journal", "tiny.h5.lock"]
