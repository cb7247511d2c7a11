"""Plugin methods (docs/plugins.md): a package of the user's declares a method through the entry-point group
``ilcforce.methods``, and every command takes it as it takes a shipped one.

The end-to-end test installs the example package of the repository (examples/ilcforce-plugin-example/) into a
fresh venv and runs simulate, a study, a tuning and the report on its method there, in processes of that venv.
The install is what an editable install writes (a .pth to the package's folder and its dist-info holding the
entry points, read from the example's own pyproject.toml): this environment has no wheel builder and the test
downloads nothing. ilcforce and its dependencies come from this checkout and this environment through a .pth.
The registry's own rules (a broken plugin is one line and is left out; loaded once) are tested in-process.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import sysconfig
import textwrap
import tomllib
from pathlib import Path

import pytest

from ilcforce import controllers
from ilcforce.controllers import ENTRY_POINT_GROUP, EntryPoint, Registry

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "ilcforce-plugin-example"
sys.path.insert(0, str(Path(__file__).resolve().parent))
from tunekit import TINY  # noqa: E402 - the tests' folder, put on the path above

SHIPPED = controllers.REGISTRY.shipped


def _install(project: Path, purelib: Path) -> None:
    """Install the package in ``project`` as an editable install does: its folder on the path, its dist-info
    (name, version and the entry points of its pyproject.toml)."""
    meta = tomllib.loads((project / "pyproject.toml").read_text())["project"]
    dist = purelib / f"{meta['name'].replace('-', '_')}-{meta['version']}.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {meta['version']}\n")
    groups = meta.get("entry-points", {})
    (dist / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{name} = {value}\n" for name, value in points.items()) + "\n"
        for group, points in groups.items()))
    (dist / "INSTALLER").write_text("tests/test_plugins.py\n")
    (purelib / f"{meta['name']}.pth").write_text(f"{project}\n")


def _venv(work: Path, *projects: Path) -> Path:
    """A fresh venv (ilcforce from this checkout, the dependencies from this environment) with ``projects``
    installed; its python."""
    venv = work / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    purelib = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                  check=True, capture_output=True, text=True).stdout.strip())
    (purelib / "zz-ilcforce-test.pth").write_text(f"{ROOT}\n{sysconfig.get_paths()['purelib']}\n")
    for project in projects:
        _install(project, purelib)
    return python


def _run(python: Path, args: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    # this checkout's numba cache (NUMBA_CACHE_DIR of the test run): the shipped kernels are not compiled again
    return subprocess.run([str(python), *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout)


@pytest.fixture(scope="module")
def plugin_python(tmp_path_factory) -> Path:
    return _venv(tmp_path_factory.mktemp("plugin"), EXAMPLE)


def test_the_example_declares_its_method_through_the_group():
    meta = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]
    assert meta["entry-points"][ENTRY_POINT_GROUP] == {"p-ilc": "ilcforce_ptype:METHOD_SPEC"}


def test_a_plugin_method_runs_through_simulate_study_tune_and_report(plugin_python, tmp_path):
    """About 30 s on 2 cores once numba's cache holds the loop (the plugin's law compiles through numba)."""
    python, results = plugin_python, tmp_path / "results"
    listed = _run(python, ["-m", "ilcforce.controllers"], tmp_path)
    assert listed.returncode == 0 and listed.stderr == "", listed.stderr
    assert listed.stdout.split() == [*SHIPPED, "p-ilc"], "the plugin's method after the shipped ones"

    ran = _run(python, ["-m", "ilcforce", "simulate", "-m", "p-ilc", "--iters", "3", "--set", "reference.duration=0.2",
                        "--set", "p-ilc.gamma=[300, 300]", "--results", str(results)], tmp_path)
    assert ran.returncode == 0, ran.stderr
    stores = sorted(results.glob("*/p-ilc.h5"))
    assert len(stores) == 1, stores
    check = _run(python, ["-c", textwrap.dedent(f"""
        from ilcforce import store
        path = {str(stores[0])!r}
        store.validate(path)  # raises for a store that is not whole, or of no registered method
        errors = store.read_metrics(path)["position_error_l2"].tolist()
        assert len(errors) == 3 and errors[2] < errors[0] / 2, errors  # it learns: the position error falls
        print(sorted(store.read_memory(path, 2)))
        """)], tmp_path)
    assert check.returncode == 0, check.stderr
    assert check.stdout.strip() == "['v']", check.stdout

    study = tmp_path / "plugin-study.toml"
    study.write_text(textwrap.dedent("""
        [study]
        name = "plugin-study"
        methods = ["c1", "p-ilc"]
        seeds = "0-1"
        [study.set]
        "experiment.iterations" = 2
        "reference.duration" = 0.2
        [study.sweep]
        "p-ilc.gamma" = [[100.0, 100.0], [300.0, 300.0]]
        """))
    ran = _run(python, ["-m", "ilcforce", "study", str(study), "--workers", "1", "--results", str(results)], tmp_path)
    assert ran.returncode == 0, ran.stderr
    assert "8 cells (0 already stored, 8 run, 0 failed)" in ran.stdout, ran.stdout

    tuning = tmp_path / "tiny.toml"
    tuning.write_text(TINY.replace('methods = ["c1", "c3"]', 'methods = ["c1", "p-ilc"]')
                      .replace("[tune.gains.c3]", "[tune.gains.p-ilc]")
                      .replace("k = [{ low = 1.0, high = 100.0, log = true }, 100.0]",
                               "gamma = [{ low = 10.0, high = 1000.0, log = true }, 300.0]")
                      .replace("eta = { low = 0.0, high = 10.0 }\n", ""))
    ran = _run(python, ["-m", "ilcforce", "tune", str(tuning), "--workers", "1", "--results", str(results)], tmp_path)
    assert ran.returncode == 0, ran.stderr
    assert re.search(r"tiny: p-ilc: 2 trials .* ships trial \d", ran.stdout), ran.stdout
    tuned = tomllib.loads((results / "tuning" / "tiny" / "tuned.toml").read_text())
    assert len(tuned["p-ilc"]["gamma"]) == 2, "the tuned experiment carries the plugin's gains"

    ran = _run(python, ["-m", "ilcforce", "report", "--results", str(results), "--jobs", "1", "-q"], tmp_path)
    assert ran.returncode == 0, ran.stderr
    report = results / "report"
    assert (report / "index.html").is_file()
    comparison = next(report.glob("*/comparison.csv")).read_text()
    assert "p-ilc" in comparison, comparison
    assert "p-ilc" in (report / "tuning" / "tiny" / "tuning.csv").read_text()


def test_the_registry_reads_the_entry_points_importlib_metadata_reads(plugin_python, tmp_path):
    """The registry's own reader of the installed entry points (ilcforce.controllers._entry_points, which spares
    every cold command importlib.metadata's import) against importlib.metadata, in the venv with the plugin."""
    code = textwrap.dedent(f"""
        import sys
        from ilcforce import controllers
        fast = [(ep.name, ep.value) for ep in controllers._entry_points()]
        assert "importlib.metadata" not in sys.modules
        from importlib.metadata import entry_points
        slow = sorted((ep.name, ep.value) for ep in entry_points(group={ENTRY_POINT_GROUP!r}))
        assert fast == slow == [("p-ilc", "ilcforce_ptype:METHOD_SPEC")], (fast, slow)
        """)
    done = _run(plugin_python, ["-c", code], tmp_path)
    assert done.returncode == 0, done.stderr


def test_a_plugin_leaves_the_ahead_of_time_kernels_current(plugin_python, tmp_path):
    """The plugin's law is not in the ahead-of-time module: it runs through numba (the test above), and the
    module stays in use for the shipped laws (its stamp covers ilcforce's own sources, not the plugin's)."""
    code = "from ilcforce.compiled import aot; print(aot.status())"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    without = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path,
                             env={**env, "PYTHONPATH": str(ROOT)}, timeout=120)
    with_plugin = _run(plugin_python, ["-c", code + "\nfrom ilcforce.controllers import REGISTRY; "
                                       "print(list(REGISTRY)[-1])"], tmp_path)
    assert with_plugin.returncode == 0, with_plugin.stderr
    status, last = with_plugin.stdout.splitlines()
    assert last == "p-ilc"
    assert status == without.stdout.strip(), "the plugin changes nothing in whether the compiled module is used"


def test_a_plugin_law_has_no_ahead_of_time_simulator(monkeypatch):
    """The loader finds no compiled loop for a law outside ilcforce.controllers, so the run takes numba's."""
    from ilcforce.compiled import aot
    from ilcforce.controllers.c2 import C2Controller
    from ilcforce.plants.fivebar import FiveBar

    monkeypatch.syspath_prepend(str(EXAMPLE))
    from ilcforce_ptype.law import PTypeController

    assert aot.law_key(PTypeController) is None and aot.law_key(C2Controller) == "c2_c2_law"
    assert aot.simulator(PTypeController, FiveBar, FiveBar) is None


def test_a_broken_plugin_is_one_line_and_the_shipped_methods_run(tmp_path):
    broken = tmp_path / "broken"
    (broken / "broken_method").mkdir(parents=True)
    (broken / "broken_method" / "__init__.py").write_text("raise RuntimeError('the law module is not finished')\n")
    (broken / "pyproject.toml").write_text(textwrap.dedent("""
        [project]
        name = "broken-method"
        version = "0.0.1"
        [project.entry-points."ilcforce.methods"]
        half-done = "broken_method:METHOD_SPEC"
        """))
    # a plugin whose law numba cannot compile: the example with a name the law does not define
    bad_law = tmp_path / "bad-law"
    (bad_law / "bad_law").mkdir(parents=True)
    source = EXAMPLE / "ilcforce_ptype"
    (bad_law / "bad_law" / "__init__.py").write_text((source / "__init__.py").read_text()
                                                     .replace("p-ilc", "bad-law").replace("ilcforce_ptype", "bad_law"))
    law = (source / "law.py").read_text().replace('"p-ilc"', '"bad-law"')
    law = law.replace("surface(n, k, meas, ref, gains, False, diag)", "surface(n, k, meas, ref, gains, False, no_such_name)")
    assert "no_such_name" in law
    (bad_law / "bad_law" / "law.py").write_text(law)
    (bad_law / "pyproject.toml").write_text(textwrap.dedent("""
        [project]
        name = "bad-law"
        version = "0.0.1"
        [project.entry-points."ilcforce.methods"]
        bad-law = "bad_law:METHOD_SPEC"
        """))
    python = _venv(tmp_path, EXAMPLE, broken, bad_law)
    ran = _run(python, ["-m", "ilcforce", "simulate", "-m", "c1", "--iters", "1", "--set", "reference.duration=0.05",
                        "--results", str(tmp_path / "results")], tmp_path)
    assert ran.returncode == 0, ran.stderr
    lines = [line for line in ran.stderr.splitlines() if "half-done" in line]
    assert lines == ["ilcforce: plugin method 'half-done' (broken_method:METHOD_SPEC of package broken_method) left out: "
                     "cannot be loaded (RuntimeError: the law module is not finished)"], ran.stderr
    listed = _run(python, ["-m", "ilcforce.controllers"], tmp_path)
    assert listed.stdout.split() == [*SHIPPED, "bad-law", "p-ilc"], "the working plugins load beside the broken one"
    failed = _run(python, ["-m", "ilcforce", "simulate", "-m", "bad-law", "--iters", "1", "--set",
                           "reference.duration=0.05", "--results", str(tmp_path / "results")], tmp_path)
    assert failed.returncode == 2, failed.stderr
    assert failed.stderr.splitlines()[-1] == ("error: the law bad_law.law.ptype_law does not compile with numba: "
                                              "NameError: name 'no_such_name' is not defined"), failed.stderr
    assert "Traceback" not in failed.stderr and not list((tmp_path / "results").glob("*/bad-law.h5"))
    study = _run(python, ["-m", "ilcforce", "study", "-m", "c1,p-ilc", "--sweep", "p-ilc.kp=[50, 50],[100, 100]",
                          "--seeds", "0", "--set", "reference.duration=0.05", "--set", "experiment.iterations=1",
                          "--workers", "2", "--results", str(tmp_path / "results")], tmp_path)
    assert study.returncode == 0, study.stderr
    assert "4 cells (0 already stored, 4 run, 0 failed)" in study.stdout, study.stdout
    said = [line for line in study.stderr.splitlines() if "half-done" in line]
    assert said == lines, "one line for the command, not one more per worker process"
    refused = _run(python, ["-m", "ilcforce", "simulate", "-m", "half-done", "--iters", "1"], tmp_path)
    assert refused.returncode == 2 and "unknown method 'half-done'" in refused.stderr, refused.stderr


# --- the registry's rules, in-process ---------------------------------------------------------------------

def _plugin_module(tmp_path: Path, monkeypatch, body: str) -> None:
    (tmp_path / "my_method.py").write_text(textwrap.dedent(body))
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("my_method", None)


_GOOD = """
    from dataclasses import dataclass
    from ilcforce.controllers import MethodSpec
    from ilcforce.controllers.base import MemoryController

    @dataclass(frozen=True)
    class Gains:
        k: tuple = (1.0, 1.0)

    class Controller(MemoryController):
        name = "{name}"
        law = staticmethod(lambda *args: 0)
        memory_layout = {{}}

    METHOD_SPEC = MethodSpec("{name}", "Mine", "Mine", "C0", "my_method", "Controller", "Gains", "none", False, {in_paper}, "me")
    """


def _registry(monkeypatch, *points: tuple[str, str]) -> Registry:
    monkeypatch.delenv(controllers._SAID, raising=False)  # this process has said nothing yet
    eps = [EntryPoint(name, value) for name, value in points]
    monkeypatch.setattr(controllers, "_entry_points", lambda: eps)
    return Registry(controllers.REGISTRY.shipped_specs())


@pytest.mark.parametrize(("name", "point", "in_paper", "problem"), [
    ("mine", ("mine", "my_method:METHOD_SPEC"), False, None),
    ("mine", ("yours", "my_method:METHOD_SPEC"), False, "the entry point is named 'yours' but its spec 'mine'"),
    ("c3", ("c3", "my_method:METHOD_SPEC"), False, "'c3' is already a method (ilcforce.controllers.c3)"),
    ("mine", ("mine", "my_method:METHOD_SPEC"), True, "in_paper must be False"),
    ("mine", ("mine", "my_method:Gains"), False, "gives a Gains, not an ilcforce.controllers.MethodSpec"),
    ("mine", ("mine", "my_method:NOTHING"), False, "cannot be loaded (AttributeError"),
    ("Mine Two", ("Mine Two", "my_method:METHOD_SPEC"), False, "'Mine Two' is not a method name"),
    ("plant", ("plant", "my_method:METHOD_SPEC"), False, "'plant' is a section of ilcforce's own files"),
])
def test_each_plugin_fault_is_one_line_naming_it(tmp_path, monkeypatch, capsys, name, point, in_paper, problem):
    _plugin_module(tmp_path, monkeypatch, _GOOD.format(name=name, in_paper=in_paper))
    registry = _registry(monkeypatch, point)
    names = list(registry)
    assert names[:len(SHIPPED)] == list(SHIPPED), "the shipped methods, whatever the plugin"
    printed = capsys.readouterr().err.splitlines()
    if problem is None:
        assert names == [*SHIPPED, "mine"] and printed == [] and registry.plugins() == ("mine",)
        assert registry["mine"].gains_class().k == (1.0, 1.0)
        return
    assert names == list(SHIPPED)
    assert len(printed) == 1 and printed == list(registry.problems()), printed
    assert printed[0].startswith(f"ilcforce: plugin method {point[0]!r} ({point[1]}) left out: ")
    assert problem in printed[0], printed[0]
    list(registry)
    assert capsys.readouterr().err == "", "said once"
    assert os.environ[controllers._SAID] == "1", "the processes this one starts do not say it again"
    list(Registry(controllers.REGISTRY.shipped_specs()))
    assert capsys.readouterr().err == ""


def test_a_controller_without_a_law_or_gains_defaults_is_left_out(tmp_path, monkeypatch, capsys):
    _plugin_module(tmp_path, monkeypatch, _GOOD.format(name="mine", in_paper=False)
                   .replace("law = staticmethod(lambda *args: 0)", "pass")
                   .replace("k: tuple = (1.0, 1.0)", "k: tuple"))
    assert list(_registry(monkeypatch, ("mine", "my_method:METHOD_SPEC"))) == list(SHIPPED)
    assert "Gains() with its defaults fails" in capsys.readouterr().err
    (tmp_path / "my_method.py").write_text((tmp_path / "my_method.py").read_text().replace("k: tuple\n", "k: tuple = (1.0, 1.0)\n"))
    sys.modules.pop("my_method", None)
    assert list(_registry(monkeypatch, ("mine", "my_method:METHOD_SPEC"))) == list(SHIPPED)
    assert "Controller has no law (law = compiled_law(...), docs/plugins.md)" in capsys.readouterr().err


def test_entry_points_are_read_once_and_only_when_the_registry_is_used(monkeypatch):
    calls = []
    monkeypatch.setattr(controllers, "_entry_points", lambda: calls.append(1) or [])
    registry = Registry(controllers.REGISTRY.shipped_specs())
    assert registry.shipped == SHIPPED and calls == [], "the shipped names need no entry point"
    assert "c3" in registry and registry["c1"].name == "c1" and len(registry) == len(SHIPPED)
    assert calls == [1]


def _law_with_a_typo(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    tau[0] = meas[0] * no_such_gain  # noqa: F821 - the fault under test
    return 0


def test_a_law_numba_cannot_compile_is_one_line_naming_it():
    from ilcforce.controllers.nd import LawError, compiled_law

    with pytest.raises(LawError) as caught:
        compiled_law(_law_with_a_typo).dispatcher()
    message = str(caught.value)
    assert "\n" not in message and "\x1b" not in message
    assert message.endswith("._law_with_a_typo does not compile with numba: NameError: name 'no_such_gain' is not "
                            "defined"), message


def test_the_reserved_names_hold_every_section_of_an_experiment_file():
    import dataclasses

    from ilcforce.config import Config

    assert {f.name for f in dataclasses.fields(Config)} <= set(controllers.RESERVED)
    assert not set(controllers.RESERVED) & set(SHIPPED)
