"""docs/findings.md's hand-written preamble says only what is true of the generated findings below it
and of the runs (issue 47 item 6: it pointed at a serial2r sl-adapt divergence line that was not there)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from ilcforce.report import readme

FINDINGS = Path(__file__).resolve().parents[1] / "docs" / "findings.md"
EXPERIMENT = Path(__file__).resolve().parents[1] / "experiments" / "serial2r.toml"
#: The line of the serial2r section the preamble quotes.
QUOTED = "Learning stability of sl-adapt not evaluable"
#: NumPy's AVX-512 dispatch targets, turned off as the preamble says.
NO_AVX512 = "X86_V4 AVX512_ICL AVX512_SPR"


def _parts() -> tuple[str, str]:
    text = FINDINGS.read_text(encoding="utf-8")
    preamble, generated = text.split(readme.BEGIN, 1)
    return preamble, generated.split(readme.END, 1)[0]


def _section(generated: str, experiment: str) -> str:
    """The single run's block of ``experiment`` in the generated findings (up to the next one)."""
    start = generated.index(f"**`{experiment}`**:")
    following = re.search(r"^\*\*`", generated[start + 1:], re.M)
    return generated[start:start + 1 + following.start()] if following else generated[start:]


def test_the_preamble_points_at_a_line_that_is_there():
    preamble, generated = _parts()
    assert f'"{QUOTED}"' in " ".join(preamble.split()), "the preamble no longer quotes the line this test checks"
    serial2r = _section(generated, "serial2r")
    assert any(line.startswith(f"* {QUOTED}") for line in serial2r.splitlines()), "the quoted line is not under serial2r"
    diverged = [line for line in serial2r.splitlines() if "sl-adapt" in line and "diverged" in line]
    assert diverged == [], f"serial2r lists a divergence of sl-adapt, which the preamble says it does not: {diverged}"
    assert "as below" not in preamble and "Stored numbers do not change" not in preamble  # the old dead pointers


def _supports_avx512() -> bool:
    code = "import numpy._core._multiarray_umath as m; print(m.__cpu_features__.get('AVX512F', False))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip() == "True"


@pytest.mark.slow
@pytest.mark.parametrize("disabled", ["", NO_AVX512])
def test_serial2r_sl_adapt_completes_with_and_without_avx512(tmp_path: Path, disabled: str):
    """The preamble's claim about the run itself: seed 0 of serial2r's sl-adapt completes its 20
    iterations with NumPy's AVX-512 code and with it turned off (about 10 s each)."""
    if disabled and not _supports_avx512():
        pytest.skip("this CPU has no AVX-512: the default run is already the one without it")
    out = tmp_path / "sl-adapt.h5"
    done = subprocess.run([sys.executable, "-m", "ilcforce", "simulate", "-c", str(EXPERIMENT), "-m", "sl-adapt",
                           "--out", str(out)], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "NPY_DISABLE_CPU_FEATURES": disabled})
    assert done.returncode == 0, done.stderr
    from ilcforce import store

    metrics = store.read_metrics(out)
    assert len(metrics) == 20 and set(metrics["status"]) == {"complete"}, metrics["status"].value_counts()
