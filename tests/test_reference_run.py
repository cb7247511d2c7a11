"""No accuracy change: a short run of the paper's setup stores exactly the numbers it stored before.

Speed work (lazy imports, parallel ``compare``, cheaper HDF5 writes, compiled tau_d) must not change
a single stored number. ``tests/data/reference_run.npz`` holds every numeric (and string) dataset of
the stores that ``ilcforce compare`` writes for c1, c2, c3 over a shrunk paper setup (3 iterations,
a 0.2 s reference, the m3 perturbation from iteration 2 so both the nominal and the perturbed plant
are exercised), as produced by the code before the speed work. The test runs the
real entry point in a fresh process and compares every reference dataset with ``np.array_equal``
(NaN equal to NaN where the reference has NaN): bit for bit, no tolerance.

Bit for bit holds on one kind of host. NumPy computes float64 sin, cos and exp with its own SIMD code
(SVML) on a CPU with AVX-512 and with the C library's elsewhere, which differ in the last bit; the
reference trajectory picks that up and the loop carries it on (measured: 119 of 225 datasets differ
by 1e-19 to 6.5e-14 between the two). So there is one reference per kind, both from that code:
``reference_run.npz`` made on an AVX-512 host, ``reference_run_no_avx512.npz`` on an AMD EPYC with
AVX2 and FMA but no AVX-512 (on which NumPy's sin/cos/exp equal glibc's, element for element), and
a run must equal one of them exactly. This code and that one give identical numbers on each host.

If a number changes on purpose (a fix to the physics, a new definition), regenerate the reference
deliberately, from the commit that makes the change, and say so in that commit:

    git worktree add /tmp/ref-tree <commit>
    NUMBA_CACHE_DIR=$PWD/.venv/numba-cache PYTHONPATH=/tmp/ref-tree \\
        .venv/bin/python tests/test_reference_run.py tests/data/reference_run.npz
    git worktree remove /tmp/ref-tree

(on an AVX-512 host; on one without, write ``reference_run_no_avx512.npz``; regenerate both.) On an AVX-512
host the other kind can be had by turning the AVX-512 code paths of NumPy and OpenBLAS off:

    OPENBLAS_CORETYPE=Haswell NPY_DISABLE_CPU_FEATURES="AVX512_ICL AVX512_SPR X86_V4" \\
        NUMBA_CACHE_DIR=... PYTHONPATH=/tmp/ref-tree .venv/bin/python tests/test_reference_run.py \\
        tests/data/reference_run_no_avx512.npz

(checked before use: the code that made the AMD EPYC file, run so on an AVX-512 host, reproduced that file
exactly, every dataset). Both files were last regenerated so at the commit that made one loop for every
robot (issue 45): against the two-loop code's files the AVX-512 one moved by at most 2.7e-14 of a dataset's
largest value, the other by at most 1.1e-16 m in C1's position error (whose largest value is 2.9e-7 m, so
3.8e-10 of it, 3e-16 of the positions it is a difference of) and 7e-12 in the metrics made from it; they also
hold the datasets a run has stored since the files were first made (the newer metric columns, the
implicit-fallback log, the control time).

(``PYTHONPATH`` makes the subprocess import ilcforce from that tree; the script checks it did.)
A dataset that only moved in the store's layout is mapped in ``RENAMED`` instead; never loosen the
comparison.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REFERENCE = Path(__file__).parent / "data" / "reference_run.npz"
#: The same run on a host without AVX-512 (module docstring): a run equals one of the two exactly.
REFERENCES = (REFERENCE, Path(__file__).parent / "data" / "reference_run_no_avx512.npz")
METHODS = ("c1", "c2", "c3")
#: The shrunk paper setup: few iterations and a short reference keep the test and the file small.
ARGS = ("compare", "--methods", ",".join(METHODS), "--iters", "3",
        "--set", "reference.duration=0.2", "--set", "plant.perturbation.from_iteration=2")
#: reference key -> key in today's stores, for datasets that only moved (none yet).
RENAMED: dict[str, str] = {}


def _run(results: Path, cwd: Path | None = None) -> None:
    proc = subprocess.run([sys.executable, "-m", "ilcforce", *ARGS, "--results", str(results)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)
    assert proc.returncode == 0, proc.stderr


def _stored_numbers(results: Path) -> dict[str, np.ndarray]:
    """Every dataset of every method's store, keyed ``<method>/<dataset path>``."""
    import h5py

    numbers: dict[str, np.ndarray] = {}
    for method in METHODS:
        found = sorted(Path(results).rglob(f"{method}.h5"))  # a --set run may live in a variant folder
        assert len(found) == 1, found
        with h5py.File(found[0], "r") as handle:
            def visit(name, item, method=method):
                if isinstance(item, h5py.Dataset):
                    value = item[()]
                    if value.dtype.kind in "OS":
                        value = np.array([v.decode() if isinstance(v, bytes) else str(v) for v in value.ravel()])
                    numbers[f"{method}/{name}"] = value
            handle.visititems(visit)
    return numbers


def _equal(expected: np.ndarray, actual: np.ndarray) -> bool:
    if expected.dtype.kind == "f":
        return np.array_equal(expected, actual, equal_nan=True)
    return np.array_equal(expected, actual)


def _host() -> str:
    from numpy._core._multiarray_umath import __cpu_features__

    return "AVX-512" if __cpu_features__.get("AVX512_SKX") else "no AVX-512"


def _differ(reference, stored: dict[str, np.ndarray]) -> list[str]:
    return [k for k in reference.files
            if reference[k].dtype != stored[RENAMED.get(k, k)].dtype and reference[k].dtype.kind != "U"
            or not _equal(reference[k], stored[RENAMED.get(k, k)])]


def test_every_stored_number_matches_the_reference(tmp_path):
    _run(tmp_path)
    stored = _stored_numbers(tmp_path)
    found = {}
    for path in REFERENCES:
        reference = np.load(path, allow_pickle=False)
        assert len(reference.files) > 100  # logs, memories, metrics and reference of 3 methods x 3 iterations
        missing = [k for k in reference.files if RENAMED.get(k, k) not in stored]
        assert not missing, f"datasets of the reference run no longer stored: {missing[:10]}"
        found[path.name] = _differ(reference, stored)
    assert any(not differ for differ in found.values()), (
        f"on this host ({_host()}) the run equals no reference: "
        + "; ".join(f"{name}: {len(d)} datasets differ, e.g. {d[:5]}" for name, d in found.items()))


@pytest.mark.parametrize("path", REFERENCES, ids=lambda p: p.stem)
def test_the_reference_covers_what_a_run_stores(path):
    reference = np.load(path, allow_pickle=False)
    assert sorted(reference.files) == sorted(np.load(REFERENCE, allow_pickle=False).files)
    for method in METHODS:
        keys = [k for k in reference.files if k.startswith(method + "/")]
        assert any("/log/" in k for k in keys) and any(k.startswith(f"{method}/reference/") for k in keys)
        assert any("/memory/" in k for k in keys) == (method != "c1")  # C1 learns nothing
        assert any(k.startswith(f"{method}/metrics/") for k in keys)
        assert any(k.startswith(f"{method}/iterations/0002/") for k in keys)  # the perturbed plant


def _write(target: Path) -> None:
    """Run the shrunk setup with whatever ilcforce PYTHONPATH selects and save every dataset."""
    import tempfile

    target = target.resolve()
    with tempfile.TemporaryDirectory() as tmp:  # run outside any tree, so PYTHONPATH decides
        probe = subprocess.run([sys.executable, "-c", "import ilcforce; print(ilcforce.__file__)"],
                               capture_output=True, text=True, check=True, cwd=tmp)
        source = Path(probe.stdout.strip()).parent.parent
        wanted = os.environ.get("PYTHONPATH", "").split(os.pathsep)[0]
        if not wanted or source.resolve() != Path(wanted).resolve():
            pytest.exit(f"ilcforce imports from {source}, not from PYTHONPATH={wanted!r}", 2)
        print(f"ilcforce from {source}")
        _run(Path(tmp) / "results", cwd=Path(tmp))
        numbers = _stored_numbers(Path(tmp) / "results")
    np.savez_compressed(target, **numbers)
    print(f"{len(numbers)} datasets -> {target} ({target.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        pytest.exit("usage: PYTHONPATH=<tree> python tests/test_reference_run.py tests/data/reference_run.npz", 2)
    _write(Path(sys.argv[1]))
