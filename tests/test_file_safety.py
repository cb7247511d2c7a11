"""Every file a command reads is opened one safe way (:func:`ilcforce.tomlfile.read_regular`), and `tune`
never writes where it must not: issue 46's hangs, wrong robots and late refusals, each reproduced with
real files, FIFOs, links and command-line processes under a timeout (a hang fails the test instead of
holding it), then attacked with variants (other special files, other MJCF file attributes, a URDF's
mesh, other aliases of an input).

The tuning stores are made in-process with the stand-in cell (:func:`tunekit.fake_cell`): these tests
time files and processes, not physics. A `tune` rerun on a finished store runs no cell.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ilcforce.tomlfile import UnreadableFile, read_regular
from tunekit import ROOT, TINY, tiny_file, tuned

#: A hang guard, not a speed claim: each guarded command takes 2-10 s here (Python, numpy, MuJoCo and
#: optuna imports on 2 shared cores); a FIFO held every one of them forever before.
HANG = 240


def cli(*args, cwd=None) -> subprocess.CompletedProcess:
    """``ilcforce ARGS`` in a process of its own, killed after :data:`HANG` s (the test then fails)."""
    return subprocess.run([sys.executable, "-m", "ilcforce", *map(str, args)], capture_output=True, text=True,
                          timeout=HANG, cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)})


def one_error_line(result: subprocess.CompletedProcess, *needles: str) -> str:
    """The one error line of a refused command (exit 2, no traceback), holding every needle."""
    text = result.stderr + result.stdout
    assert result.returncode == 2, text
    assert "Traceback" not in text and len(result.stderr.strip().splitlines()) == 1, text
    for needle in needles:
        assert needle in result.stderr, result.stderr
    return result.stderr.strip()


def tune_again(tmp_path, *args):
    return cli("tune", tiny_file(tmp_path, TINY), "--results", tmp_path / "r", "--workers", "1", "-q", *args)


# ------------------------------------------------------------------------------------------------
# the one safe open


@pytest.fixture
def specials(tmp_path):
    """name -> a path that is no regular file, with the reason read_regular gives."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "sock"))
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "zero").symlink_to("/dev/zero")
    (tmp_path / "folder").mkdir()
    yield {"fifo": (fifo, "is a FIFO (named pipe), not a regular file"),
           "socket": (tmp_path / "sock", "is a socket, not a regular file"),
           "dangling link": (tmp_path / "dangling", "is a symbolic link that leads nowhere"),
           "link loop": (tmp_path / "loop", "is a symbolic link that leads nowhere"),
           "link to /dev/zero": (tmp_path / "zero", "is a character device, not a regular file"),
           "/dev/zero": (Path("/dev/zero"), "is a character device, not a regular file"),
           "directory": (tmp_path / "folder", "is a directory"),
           "missing": (tmp_path / "missing", "does not exist"),
           "under a file": (Path(__file__) / "x", "does not exist")}
    sock.close()


def test_read_regular_refuses_every_special_file_at_once(specials, tmp_path):
    for name, (path, reason) in specials.items():
        start = time.monotonic()
        with pytest.raises(UnreadableFile) as caught:
            read_regular(path, 1 << 20)
        assert str(caught.value).startswith(reason), (name, str(caught.value))
        assert time.monotonic() - start < 1.0, name  # nothing waited on: a FIFO used to block forever
    plain = tmp_path / "plain"
    plain.write_bytes(b"x" * 100)
    assert read_regular(plain, 100) == b"x" * 100
    with pytest.raises(UnreadableFile, match="is larger than 99 bytes"):
        read_regular(plain, 99)
    link = tmp_path / "link"
    link.symlink_to(plain)
    assert read_regular(link, 100) == b"x" * 100
    with pytest.raises(UnreadableFile, match="^is a symbolic link$"):
        read_regular(link, 100, follow_links=False)


def test_every_toml_loader_refuses_special_files_in_bounded_time(specials, tmp_path):
    """The experiment, study and tuning loaders, and `simulate -c` through a FIFO (a process)."""
    from ilcforce.config import ConfigError
    from ilcforce.config_load import load_config
    from ilcforce.study.spec import StudyError, load_study
    from ilcforce.tune.spec import TuneError, load_tuning

    for name, (path, reason) in specials.items():
        for load, error in ((load_config, ConfigError), (load_study, StudyError), (load_tuning, TuneError)):
            with pytest.raises(error, match=reason.split(",")[0].replace("(", r"\(").replace(")", r"\)")):
                load(path)
    result = cli("simulate", "-c", specials["fifo"][0], "-n", "1")
    one_error_line(result, "is a FIFO (named pipe), not a regular file")


# ------------------------------------------------------------------------------------------------
# item 9: the tuning store's tuned.toml and heldout/


def test_a_fifo_at_tuned_toml_neither_hangs_validate_nor_tune_and_tune_repairs_it(tmp_path):
    first = tuned(tmp_path, TINY)
    sealed = (first.path / "tuned.toml").read_bytes()
    (first.path / "tuned.toml").unlink()
    os.mkfifo(first.path / "tuned.toml")
    refused = cli("validate", first.path)
    assert refused.returncode == 2 and "tuned.toml: not the tuned file the last run wrote (it is a FIFO" in \
        refused.stdout + refused.stderr, refused.stdout + refused.stderr
    again = tune_again(tmp_path)
    assert again.returncode == 0, again.stderr
    assert (first.path / "tuned.toml").is_file() and (first.path / "tuned.toml").read_bytes() == sealed
    assert cli("validate", first.path).returncode == 0


@pytest.mark.parametrize("target", ["/dev/zero", "outside copy"])
def test_a_link_at_tuned_toml_is_never_followed_and_tune_replaces_it(tmp_path, target):
    """A link to /dev/zero read until MemoryError; a link out of the store to a copy of the sealed text
    was followed, and `tune` then left it (the text matched) while `validate` kept asking for a rerun."""
    first = tuned(tmp_path, TINY)
    tuned_file = first.path / "tuned.toml"
    sealed = tuned_file.read_bytes()
    outside = tmp_path / "elsewhere.toml"
    outside.write_bytes(sealed)
    tuned_file.unlink()
    tuned_file.symlink_to(target if target.startswith("/") else outside)
    refused = cli("validate", first.path)
    text = refused.stdout + refused.stderr
    assert refused.returncode == 2 and "(it is a symbolic link); rerun `ilcforce tune`" in text, text
    again = tune_again(tmp_path)
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
    assert not tuned_file.is_symlink() and tuned_file.read_bytes() == sealed
    assert outside.read_bytes() == sealed  # the link's target is never written
    assert cli("validate", first.path).returncode == 0


def test_a_symlinked_heldout_folder_is_refused_like_trials(tmp_path):
    one, other = tuned(tmp_path, TINY, results="one"), tuned(tmp_path, TINY, results="two")
    before = sorted(p.name for p in (other.path / "heldout").iterdir())
    shutil.rmtree(one.path / "heldout")
    (one.path / "heldout").symlink_to(other.path / "heldout")
    for overwrite in (False, True):
        result = cli("tune", tiny_file(tmp_path, TINY), "--results", tmp_path / "one", "--workers", "1", "-q",
                     *(["--overwrite"] if overwrite else []))
        one_error_line(result, f"{one.path / 'heldout'}: not a folder of this store (a link or a file); move it away")
    assert sorted(p.name for p in (other.path / "heldout").iterdir()) == before  # never written through
    (one.path / "heldout").unlink()
    (one.path / "heldout").write_text("not a folder")
    one_error_line(tune_again_in(tmp_path, "one"), "heldout: not a folder of this store")


def tune_again_in(tmp_path, results):
    return cli("tune", tiny_file(tmp_path, TINY), "--results", tmp_path / results, "--workers", "1", "-q")


def test_a_folder_at_tuned_toml_is_refused_before_any_trial(tmp_path):
    first = tuned(tmp_path, TINY)
    (first.path / "tuned.toml").unlink()
    (first.path / "tuned.toml").mkdir()
    (first.path / "tuned.toml" / "mine").write_text("kept")
    one_error_line(tune_again(tmp_path), "tuned.toml: a folder where the store keeps its tuned file; move it away")
    refused = cli("validate", first.path)
    assert refused.returncode == 2 and "(it is a directory); move it away" in refused.stdout + refused.stderr
    assert (first.path / "tuned.toml" / "mine").read_text() == "kept"
