"""A 2-joint arm from a model file in an experiment (docs/model.md#model-file): ``[plant] model = "file_arm"``.

* Its five kernels (``ilcforce.plants.planar_kernels``, the chain kernels with n = 2) equal the
  closed-form Serial2R's on random states, for experiments/models/serial2r.xml, to 1e-12 relative:
  per kernel, the largest difference over the tuple divided by the tuple's largest entry (entries
  that are zero in closed form come out at round-off, so an entry-wise relative test is meaningless
  there). Measured on 1,000 states: kin 2e-16, dyn 8e-16, accel 4e-15, task 2e-14 (J^-1 near the
  singular poses), ik 1.3e-14 rad.
* experiments/serial2r-model.toml (serial2r.toml with the robot from the file) runs C1, C2 and C3.
* A 20-iteration C2 run stores the closed-form arm's numbers to round-off. Measured (seed 0): the
  logged positions differ by at most 2.5e-16 m (about 4 ulp of 0.4 m), contact forces by 1.7e-13 N
  (the wall's 1000 N/m times those ulps), torques by 3.8e-13 N m at j = 0 growing to 6.4e-12 N m at
  j = 19 (C2's learned memory carries the difference forward), and every metric by at most 4.4e-11
  relative: a force error max of 2.5e-3 N differing by 1.1e-13 N, an RMS position error of 3e-6 m by
  7e-17 m. The differences are the kernels' round-off (the RNEA/CRBA sums are not the closed form's)
  and nothing else: the tolerances below are 10-20x the measured values, in the quantities' own units.
* Every model-file error reaches the command line as one line and exit 2.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

pytest.importorskip("mujoco")

from ilcforce.cli.main import app  # noqa: E402
from ilcforce.config_load import load_config  # noqa: E402
from ilcforce.plants import make_plant  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODEL_EXPERIMENT = ROOT / "experiments" / "serial2r-model.toml"
CLOSED_FORM = ROOT / "experiments" / "serial2r.toml"
MODELS = ROOT / "experiments" / "models"


@pytest.fixture(scope="module")
def pair():
    """(file plant, closed-form plant) configurations of the same arm."""
    return load_config(MODEL_EXPERIMENT), load_config(CLOSED_FORM)


def _scale_error(ours, theirs) -> float:
    ours, theirs = np.asarray(ours, dtype=float), np.asarray(theirs, dtype=float)
    return float(np.max(np.abs(ours - theirs)) / max(1e-300, np.max(np.abs(theirs))))


@pytest.mark.parametrize("iteration", [0, 10], ids=["nominal", "perturbed"])
def test_the_kernels_equal_serial2rs(pair, iteration):
    file_config, closed_config = pair
    ours = make_plant(file_config.plant.true_plant(iteration))
    theirs = make_plant(closed_config.plant.true_plant(iteration))
    a, b = ours.calls(), theirs.calls()
    rng = np.random.default_rng(7)
    worst = dict.fromkeys(("kin", "dyn", "task", "accel", "ik"), 0.0)
    for _ in range(300):
        th = (rng.uniform(-np.pi, np.pi), rng.uniform(0.05, np.pi - 0.05))  # the working mode, off its edges
        dth = tuple(rng.uniform(-4.0, 4.0, 2))
        worst["kin"] = max(worst["kin"], _scale_error(a.kin(ours.address, *th), b.kin(theirs.address, *th)))
        for kind in ("dyn", "task", "accel"):
            mine = getattr(a, kind)(ours.address, *th, *dth)
            other = getattr(b, kind)(theirs.address, *th, *dth)
            assert mine[0] == other[0] == 1.0
            worst[kind] = max(worst[kind], _scale_error(mine, other))
        P = theirs.forward_kinematics(th)
        worst["ik"] = max(worst["ik"], _scale_error(a.ik(ours.address, *P), b.ik(theirs.address, *P)))
    assert max(worst.values()) < 1e-12, worst
    # outside the working mode both say so
    assert a.kin(ours.address, 0.3, -0.5)[0] == b.kin(theirs.address, 0.3, -0.5)[0] == 0.0


def test_the_task_plane_and_the_perturbation(pair):
    file_config, _ = pair
    plant = make_plant(file_config.plant.nominal())
    np.testing.assert_array_equal(np.abs(plant.task_axes), [[1, 0, 0], [0, 0, 1]])  # model x, z -> task x, y
    assert plant.has_gravity and "elbow up" in plant.working_mode
    assert file_config.plant.perturbation.parameter == "link2.mass"
    assert Path(file_config.plant.nominal().path) == MODELS / "serial2r.xml"  # relative to the experiment file
    # the default perturbation is the last link's mass; a link's inertia may be named too
    config = load_config(MODEL_EXPERIMENT, {"plant.perturbation.parameter": ""})
    assert config.plant.perturbation.parameter == "link2.mass"
    heavier = make_plant(config.plant.true_plant(10)).joint_inertia((0.2, 1.0))
    lighter = make_plant(config.plant.true_plant(0)).joint_inertia((0.2, 1.0))
    assert heavier[1, 1] > lighter[1, 1]
    load_config(MODEL_EXPERIMENT, {"plant.perturbation.parameter": "link1.inertia"})


def test_the_elbow_down_working_mode(pair):
    down = load_config(MODEL_EXPERIMENT, {"plant.file_arm.elbow": "down", "simulation.initial_position": [0.35, 0.4]})
    plant = make_plant(down.plant.nominal())
    theta = plant.inverse_kinematics((0.35, 0.4))
    assert theta[1] < 0 and np.allclose(plant.forward_kinematics(theta), (0.35, 0.4), atol=1e-12)
    assert "elbow down" in plant.working_mode


def test_c1_c2_c3_run_on_the_file_arm(tmp_path):
    result = CliRunner().invoke(app, ["compare", "-c", str(MODEL_EXPERIMENT), "--methods", "c1,c2,c3", "--iters", "3",
                                      "--results", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "serial2r-model").glob("*.h5")) == ["c1.h5", "c2.h5", "c3.h5"]


@pytest.mark.parametrize("iterations", [4, pytest.param(20, marks=pytest.mark.slow)])
def test_a_c2_run_stores_the_closed_form_arms_numbers(iterations):
    """Four iterations in the fast suite (the file arm's chain kernels run ~35x slower than the closed form:
    20 iterations take ~17 s), the whole 20 with the slow tests; the tolerances are those measured on 20."""
    from ilcforce.experiment import simulate_iterations
    from ilcforce.metrics import iteration_metrics

    runs = [list(simulate_iterations(load_config(path, {"experiment.iterations": iterations}), "c2"))
            for path in (MODEL_EXPERIMENT, CLOSED_FORM)]
    ours, theirs = runs
    assert [r.status for r in ours] == [r.status for r in theirs] == ["complete"] * iterations
    for mine, other in zip(ours, theirs):
        log, ref = mine.log, other.log
        assert np.max(np.abs(log["position"] - ref["position"])) < 4e-15  # m; measured 2.5e-16
        assert np.max(np.abs(log["contact_force"] - ref["contact_force"])) < 2e-12  # N; measured 1.7e-13
        assert np.max(np.abs(log["torque"] - ref["torque"])) < 1e-10  # N m; measured up to 6.4e-12 (j = 19)
        m, r = iteration_metrics(mine), iteration_metrics(other)
        for key, value in r.items():
            if isinstance(value, float) and np.isfinite(value):
                assert abs(m[key] - value) <= 1e-9 * abs(value), (mine.iteration, key, m[key], value)  # measured 4.4e-11


def test_sl_adapts_regressor_comes_from_the_files_parameters(pair):
    """Y(q, dq, dq_r, ddq_r) a = Dq ddq_r + Cq(q, dq) dq_r + G_q with the base parameters of the file's
    arm (the chain's regressor, reduced to its identifiable columns); measured 4e-15 relative."""
    from ilcforce.plants import adaptive

    nominal = pair[0].plant.nominal()
    names = adaptive.base_parameter_names("file_arm", nominal)
    assert names == ("link1.mcx", "link1.mcz", "link1.Iyy", "link2.mcx", "link2.mcz", "link2.Iyy")
    a = adaptive.base_parameters(nominal)
    # the closed form's: g1 / g = m1 Lc1 + m2 L1, a - d = I1 + m1 Lc1^2 + m2 L1^2, g2 / g = m2 Lc2, d = I2 + m2 Lc2^2
    np.testing.assert_allclose(a[[0, 2, 3, 5]], [0.525, 0.15925, 0.135, 0.027], rtol=1e-13)
    plant = make_plant(nominal)
    p = np.concatenate([plant.packed, np.zeros(adaptive.PARAM_ROOM - plant.packed.size)])  # as a law's gains hold it
    code = adaptive.code("file_arm")
    rng = np.random.default_rng(3)
    for _ in range(50):
        th = np.array([rng.uniform(-3, 3), rng.uniform(0.1, 3)])
        d, r, rr = rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2), rng.uniform(-5, 5, 2)
        Y = np.array(adaptive.regressor(code, p, *th, *d, *r, *rr)).reshape(2, adaptive.REGRESSOR_WIDTH)
        want = plant.joint_inertia(th) @ rr + plant.joint_coriolis(th, d) @ r + plant.gravity(th)
        assert np.max(np.abs(Y[:, :a.size] @ a - want)) < 1e-13 * np.max(np.abs(want))
        np.testing.assert_allclose(adaptive.jacobian_derivative(code, p, *th, *d),
                                   plant.jacobian_derivative(th, d).ravel(), rtol=0, atol=1e-14)


# -- every model-file error: one line, exit 2 ------------------------------------------------------------

HINGE_Y = 'type="hinge" axis="0 1 0"'
BODY = '<body name="{name}" pos="{pos}"><joint name="j{name}" {joint}/><inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>{inner}</body>'


def _arm(second_joint=HINGE_Y, extra="", first_joint=HINGE_Y, tip='<site name="tool" pos="0.3 0 0"/>') -> str:
    inner = BODY.format(name="b", pos="0.35 0 0", joint=second_joint, inner=tip)
    return f"<mujoco><worldbody>{BODY.format(name='a', pos='0 0 0', joint=first_joint, inner=inner)}</worldbody>{extra}</mujoco>"


def _experiment(tmp_path: Path, model_text: str | None, end_effector="tool", name="arm.xml", path=None) -> Path:
    if model_text is not None:
        (tmp_path / name).write_text(model_text, encoding="utf-8")
    experiment = tmp_path / "exp.toml"
    experiment.write_text(f'[plant]\nmodel = "file_arm"\n[plant.file_arm]\npath = "{path or name}"\n'
                          f'end_effector = "{end_effector}"\n', encoding="utf-8")
    return experiment


def _one_clear_line(tmp_path, experiment: Path, expected: str, method="c2"):
    result = CliRunner().invoke(app, ["simulate", "-c", str(experiment), "-m", method, "-n", "1",
                                      "--out", str(tmp_path / "out.h5")])
    text = result.output.strip()
    assert result.exit_code == 2, f"exit {result.exit_code}: {text}"
    assert "Traceback" not in text and (result.exception is None or isinstance(result.exception, SystemExit))
    assert len(text.splitlines()) == 1, text
    assert expected in text, text
    return text


def test_a_model_file_error_is_one_line_and_exit_2(tmp_path):
    _one_clear_line(tmp_path, _experiment(tmp_path, None, name="nowhere.xml"), "nowhere.xml: no such model file")
    closed = _arm(extra='<equality><connect body1="b" body2="world" anchor="0 0 0"/></equality>')
    _one_clear_line(tmp_path, _experiment(tmp_path, closed), "closed chain")
    _one_clear_line(tmp_path, _experiment(tmp_path, _arm(first_joint='type="free"')), "floating base")
    text = _one_clear_line(tmp_path, _experiment(tmp_path, _arm(), end_effector="tcp"), "no end effector 'tcp'")
    assert "links (bodies): a, b; sites: tool" in text
    _one_clear_line(tmp_path, _experiment(tmp_path, None, path=str(MODELS / "arm3.xml")),
                    "the robot has 3 joints but the task has 2 dimensions")
    _one_clear_line(tmp_path, _experiment(tmp_path, _arm(second_joint='type="hinge" axis="0 0 1"')), "are not parallel")
    _one_clear_line(tmp_path, _experiment(tmp_path, _arm(second_joint='type="slide" axis="1 0 0"')),
                    "needs two revolute (hinge) joints")
    experiment = _experiment(tmp_path, _arm())
    experiment.write_text(experiment.read_text() + '[plant.perturbation]\nparameter = "m2"\n')
    _one_clear_line(tmp_path, experiment, "must be one of a.mass, a.inertia, b.mass, b.inertia")


def test_a_relative_path_is_the_experiment_files_and_an_override_the_working_directorys(tmp_path, monkeypatch):
    folder = tmp_path / "deep"
    folder.mkdir()
    (folder / "models").mkdir()
    (folder / "models" / "arm.xml").write_text(_arm(), encoding="utf-8")
    experiment = folder / "exp.toml"
    experiment.write_text('[plant]\nmodel = "file_arm"\n[plant.file_arm]\npath = "models/arm.xml"\nend_effector = "tool"\n')
    monkeypatch.chdir(tmp_path)
    assert load_config(experiment).plant.nominal().path == str(folder / "models" / "arm.xml")
    moved = load_config(experiment, {"plant.file_arm.path": "deep/models/arm.xml"})
    assert moved.plant.nominal().path == str(folder / "models" / "arm.xml")
    assert load_config(experiment, {"plant.file_arm.path": "serial2r.xml"}).plant.nominal().path == str(MODELS / "serial2r.xml")


def test_the_docs_api_example_runs():
    import re
    import subprocess
    import sys

    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    match = re.search(r"<!-- file-arm-example: run by tests/test_plant_file.py -->\s*```python\n(.*?)```", text, re.S)
    assert match, "docs/api.md has no marked file-arm example"
    done = subprocess.run([sys.executable, "-c", match.group(1)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0].startswith("0 complete ") and done.stdout.splitlines()[1].startswith("1 complete ")
