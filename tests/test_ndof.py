"""The n-joint loop and the laws in n dimensions (docs/model.md#n-dof), on the 3-joint spatial arm
(experiments/arm3.toml): the desired input tau_d equals the task-space model of eq. (4) along the path, the
methods learn, each law against a readable reference, and the configuration refuses what cannot run in one
line. (The planar robots run the same loop and laws with n = 2: tests/test_controllers.py, tests/test_simulate.py.)
"""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

import numpy as np
import pytest

from ilcforce import simulate
from ilcforce.config import ConfigError
from ilcforce.config_load import load_config
from ilcforce.controllers import REGISTRY
from ilcforce.experiment import make_controller, simulate_iterations

ROOT = Path(__file__).resolve().parents[1]
ARM3 = ROOT / "experiments" / "arm3.toml"
#: every method (each has one law, for any n)
METHODS = tuple(REGISTRY)
#: the methods whose gains follow the shared layout (sl-adapt's Gamma is as wide as the plant's base
#: parameters, so its layout is its own: test_sl_adapt_on_three_axes_is_slotine_li reads it)
SHARED_LAYOUT = tuple(name for name in METHODS if name != "sl-adapt")


@pytest.fixture(scope="module")
def arm3():
    return load_config(ARM3)


def test_arm3_desired_input_is_the_task_space_model_along_the_path(arm3):
    """tau_d (inverse dynamics by the chain's RNEA, ilcforce.plants.desired_nd) against eq. (4)'s task-space model
    D ddX + C dX + G + w F (the chain's CRBA and Christoffel symbols), rotated into the wall's frame."""
    from ilcforce.plants import make_plant

    robot = make_plant(arm3.plant.nominal())
    frame = arm3.wall.frame(3)
    ref = arm3.reference_samples()[::400]
    tau_d, task_d = simulate.desired_inputs(arm3.plant.nominal(), arm3.wall, ref)
    q = None
    for k in range(ref.shape[0]):
        P = frame.T @ ref[k, 0:3]
        q = robot.inverse_kinematics(P) if q is None else robot.inverse_kinematics(P, q)
        dq = np.linalg.solve(robot.jacobian(q), frame.T @ ref[k, 3:6])
        # world-frame task model, rotated: X = R P, so D_X = R D R^T, C_X = R C R^T, G_X = R G
        D = frame @ robot.task_inertia(q) @ frame.T
        C = frame @ robot.task_coriolis(q, dq) @ frame.T
        G = frame @ robot.task_gravity(q)
        expected = D @ ref[k, 6:9] + C @ ref[k, 3:6] + G + arm3.wall.sign * ref[k, 9:12]
        np.testing.assert_allclose(task_d[k], expected, rtol=1e-9, atol=1e-9 * np.max(np.abs(expected)))
        np.testing.assert_allclose(tau_d[k], (frame @ robot.jacobian(q)).T @ task_d[k], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", ["c1", "c2", "c3"])
def test_arm3_methods_complete_and_the_learning_ones_learn(arm3, method):
    config = dataclasses.replace(arm3, experiment=dataclasses.replace(arm3.experiment, iterations=4))
    records = list(simulate_iterations(config, method))
    assert [r.status for r in records] == ["complete"] * 4
    for r in records:
        assert r.log["position"].shape == (config.n_log, 3)
    rms = [(np.sqrt(np.mean(np.sum(r.log["position_error"] ** 2, axis=1))),
            np.sqrt(np.mean(np.sum(r.log["force_error"] ** 2, axis=1)))) for r in records]
    if method != "c1":  # j = 0 -> 3 (the study of experiments/full/arm3-mc.toml runs 20 iterations on 20 seeds)
        assert rms[3][0] < rms[0][0] / 10
        assert rms[3][1] < rms[0][1] / 2
    # the force acts along the wall's normal only (the wall is frictionless), in the wall's frame
    force = records[-1].log["contact_force"]
    assert np.all(force[:, :2] == 0.0) and np.max(force[:, 2]) > 20.0


def test_the_report_draws_a_three_axis_run_along_its_axes(arm3, tmp_path):
    """Every single-run figure of a 3-axis run is drawn, Figs. 6 and 7 once per axis (u, v in the plane; n, the
    force axis), and the report names them with their captions: none is "not drawn"."""
    from ilcforce.experiment import run_method
    from ilcforce.report.build import write_report
    from ilcforce.report.run_figures import figure_captions

    config = dataclasses.replace(arm3, experiment=dataclasses.replace(arm3.experiment, iterations=2))
    for method in ("c1", "c3"):
        run_method(config, method, tmp_path / "results" / "arm3" / f"{method}.h5")
    write_report(tmp_path / "results", tmp_path / "report")
    page = (tmp_path / "report" / "arm3" / "report.md").read_text()
    stems = list(figure_captions({"surface": {"selection": list(arm3.surface.selection)}}))
    assert [s for s in stems if s.startswith(("fig6", "fig7"))] == ["fig6_input_u", "fig6_input_v", "fig7_input_n"]
    for stem in stems:
        assert (tmp_path / "report" / "arm3" / f"{stem}.png").is_file(), stem
    assert "Not drawn" not in page
    assert "desired position u_d and v_d (m) and desired contact force F_nd (N) along the n axis" in page


def test_arm3_refusals_are_one_line(arm3, tmp_path):
    text = ARM3.read_text()
    cases = {
        "selection": (text.replace("selection = [0.0, 0.0, 1.0]", "selection = [0.0, 1.0]")
                      .replace("lambda_p = [2.0, 2.0, 0.0]", "lambda_p = [2.0, 0.0]")
                      .replace("lambda_f1 = [0.0, 0.0, 1e-3]", "lambda_f1 = [0.0, 1e-3]")
                      .replace("lambda_f2 = [0.0, 0.0, 1e-4]", "lambda_f2 = [0.0, 1e-4]"), "has 3 joints"),
        "normal": (text.replace("normal = [0.342, 0.0, -0.940]", "normal = [0.0, 0.0]"), "wall.normal"),
        "parallel": (text.replace("tangent = [1.0, 0.0, 0.0]", "tangent = [0.342, 0.0, -0.940]"), "parallel"),
        "gains": (text.replace("k = [400.0, 400.0, 10000.0]", "k = [400.0, 10000.0]"), "c2"),
        "posture": (text.replace("posture = [0.0, 0.3, -1.2]", "posture = [0.0, 0.3]"), "posture"),
        "start": (text.replace("initial_position = [0.56, 0.0, 0.06]", "initial_position = [0.56, 0.06]"),
                  "initial_position"),
    }
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "arm3.xml").write_text((ARM3.parent / "models" / "arm3.xml").read_text())
    for name, (body, words) in cases.items():
        path = tmp_path / f"{name}.toml"
        path.write_text(body)
        with pytest.raises(ConfigError) as caught:
            config = load_config(path)
            make_controller(config, "c2")
        message = str(caught.value)
        assert "\n" not in message and words in message, (name, message)
    # sl-adapt's Gamma: one entry per base parameter of the arm (15), not per axis
    body = text.replace("gamma = [1.0, 10.4, 10.4, 1.0,", "gamma = [10.4, 10.4, 1.0,")
    (tmp_path / "gamma.toml").write_text(body)
    with pytest.raises(ConfigError, match=r"^sl-adapt.gamma must have 15 entries, one per base parameter") as caught:
        make_controller(load_config(tmp_path / "gamma.toml"), "sl-adapt")
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("method", SHARED_LAYOUT)
def test_the_gains_are_packed_where_the_law_reads_them(method):
    """Every field of every method sits, for n = 2 and n = 3, where the law's offsets (gain_offsets) say, and
    the fields follow each other without a gap (pack_gains fills gain_layout)."""
    import dataclasses as dc

    from ilcforce.controllers.base import gain_layout
    from ilcforce.controllers.nd import at_py, gain_offsets

    gains_cls = REGISTRY[method].gains_class
    names = tuple(f.name for f in dc.fields(gains_cls))
    for n in (2, 3):
        layout = gain_layout(gains_cls, n=n)
        assert [layout[name].start for name in names] == [at_py(o, n) for o in gain_offsets(gains_cls, *names)]
        assert all(layout[a].stop == layout[b].start for a, b in zip(names, names[1:])), (method, n)


# --- the n-axis laws' contract on the spatial arm, and C1 and C3 against readable references -----------

def _measurement_nd(rng, config):
    """A consistent n-axis measurement at a random pose near arm3's path (nominal model, wall frame)."""
    from ilcforce.controllers import nd
    from ilcforce.plants import make_plant

    n = config.dimension
    robot = make_plant(config.plant.nominal())
    frame = config.wall.frame(n)
    X = config.reference_samples()[rng.integers(0, config.n_control), 0:n] + rng.normal(0.0, 0.005, n)
    q = robot.inverse_kinematics(frame.T @ X)
    dq = rng.normal(0.0, 0.5, n)
    JX = frame @ robot.jacobian(q)
    meas = np.zeros(nd.at_py(nd.M_WIDTH, n))

    def put(offset, values):
        start = nd.at_py(offset, n)
        meas[start:start + np.size(values)] = np.ravel(values)

    put(nd.M_THETA, q)
    put(nd.M_DTHETA, dq)
    put(nd.M_FORCE, np.r_[rng.normal(0, 0.01, n - 1), config.wall.stiffness * max(0.0, X[-1] - config.wall.position)])
    put(nd.M_POSITION, X)
    put(nd.M_VELOCITY, JX @ dq)
    put(nd.M_JACOBIAN, JX)
    put(nd.M_ACCEL, rng.normal(0.0, 1.0, n))
    put(nd.M_FORCE_RATE, rng.normal(0.0, 10.0, n))
    put(nd.M_FORCE_ACCEL, rng.normal(0.0, 100.0, n))
    put(nd.M_TASK_INERTIA, frame @ robot.task_inertia(q) @ frame.T)
    put(nd.M_TASK_CORIOLIS, frame @ robot.task_coriolis(q, dq) @ frame.T)
    put(nd.M_TASK_GRAVITY, frame @ robot.task_gravity(q))
    return meas, JX


def _diag(controller, n):
    """The diag array the n-joint loop gives the law: the shared entries, then the law's own scratch."""
    from ilcforce.controllers import nd

    return np.zeros(nd.diag_width(n) + getattr(controller, "nd_scratch", 0))


def _law_inputs(config, method, seed):
    rng = np.random.default_rng(seed)
    controller = make_controller(config, method)
    width = max((stop for _a, stop, _u in controller.memory_layout.values()), default=0)
    meas, JX = _measurement_nd(rng, config)
    ref = np.ascontiguousarray(rng.normal(0.0, 1.0, (50, 6 * config.dimension)))
    return controller, meas, JX, ref, rng.normal(0.0, 1.0, (50, width))


@pytest.mark.parametrize("method", METHODS)
def test_a_law_on_three_axes_is_pure_unless_writing_and_quadratic_in_the_normal_acceleration(arm3, method):
    from ilcforce.controllers import nd

    n = arm3.dimension
    controller, meas, _JX, ref, mem_prev = _law_inputs(arm3, method, 1)
    law = type(controller).law
    assert law.nopython_signatures[0].args == nd.law_signature().args
    mem_new = np.full_like(mem_prev, 7.0)
    before = mem_prev.copy()
    tau, tau_w = np.zeros(n), np.zeros(n)
    law(3, 0.0003, meas, ref, controller.gains(), mem_prev, mem_new, False, _diag(controller, n), tau)
    assert np.all(np.isfinite(tau)) and np.any(tau != 0.0)
    np.testing.assert_array_equal(mem_new, 7.0)
    law(3, 0.0003, meas, ref, controller.gains(), mem_prev, mem_new, True, _diag(controller, n), tau_w)
    np.testing.assert_array_equal(tau_w, tau)
    np.testing.assert_array_equal(mem_prev, before)
    if mem_prev.shape[1]:
        assert not np.any(mem_new[3] == 7.0)
        np.testing.assert_array_equal(np.delete(mem_new, 3, axis=0), 7.0)
    # the implicit scheme's premise: tau is a polynomial of degree <= 2 in the normal axis's acceleration
    a_at, fa_at = nd.at_py(nd.M_ACCEL, n) + n - 1, nd.at_py(nd.M_FORCE_ACCEL, n) + n - 1
    taus = []
    for a in np.arange(-2, 3) * 0.7:
        meas[a_at], meas[fa_at] = a, arm3.wall.stiffness * a
        out = np.zeros(n)
        law(5, 0.0, meas, ref, controller.gains(), mem_prev, mem_new, False, _diag(controller, n), out)
        taus.append(out)
    np.testing.assert_allclose(np.diff(np.array(taus), n=3, axis=0), 0.0, atol=1e-9)


def _reference_surface_nd(config, meas, ref_row, psi_desired):
    """sigma (eq. 8) and Psi's blocks (eq. 12) with explicit matrices, n axes."""
    from ilcforce.controllers import nd

    n = config.dimension

    def block(offset, width=n):
        start = nd.at_py(offset, n)
        return meas[start:start + width]

    S = np.diag(config.surface.selection)
    Sbar = np.eye(n) - S
    lam_p, lam_f1, lam_f2 = (np.diag(getattr(config.surface, k)) for k in ("lambda_p", "lambda_f1", "lambda_f2"))
    P, dP, ddP = block(nd.M_POSITION), block(nd.M_VELOCITY), block(nd.M_ACCEL)
    F, dF, ddF = block(nd.M_FORCE), block(nd.M_FORCE_RATE), block(nd.M_FORCE_ACCEL)
    Pd, dPd, ddPd, Fd, dFd, ddFd = (ref_row[b * n:(b + 1) * n] for b in range(6))
    e_p, de_p = Sbar @ (Pd - P), Sbar @ (dPd - dP)  # eq. (6)
    e_f, de_f, dde_f = S @ (Fd - F), S @ (dFd - dF), S @ (ddFd - ddF)  # eq. (7)
    sigma = lam_p @ e_p + de_p + lam_f1 @ e_f + lam_f2 @ de_f  # eq. (8)
    psi1 = lam_p @ de_p + lam_f1 @ de_f + lam_f2 @ dde_f + Sbar @ ddPd + S @ (ddPd if psi_desired else ddP)
    return sigma, psi1, dP + sigma, F


@pytest.mark.parametrize("seed", range(3))
def test_c1_on_three_axes_is_eq26(arm3, seed):
    from ilcforce.controllers import nd

    n = arm3.dimension
    controller, meas, JX, ref, _ = _law_inputs(arm3, "c1", seed)
    sigma, psi1, psi2, F = _reference_surface_nd(arm3, meas, ref[4], False)
    D = meas[nd.at_py(nd.M_TASK_INERTIA, n):][:n * n].reshape(n, n)
    C = meas[nd.at_py(nd.M_TASK_CORIOLIS, n):][:n * n].reshape(n, n)
    G = meas[nd.at_py(nd.M_TASK_GRAVITY, n):][:n]
    g = arm3.gains["c1"]
    u = np.diag(g.k) @ sigma + g.alpha * np.sign(sigma) + D @ psi1 + C @ psi2 + G + arm3.wall.sign * F  # eq. (26)
    tau = np.zeros(n)
    type(controller).law(4, 0.0004, meas, ref, controller.gains(), np.zeros((50, 0)), np.zeros((50, 0)), False,
                         _diag(controller, n), tau)
    np.testing.assert_allclose(tau, JX.T @ u, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_c3_on_three_axes_is_eq14_with_theta_in_r_3n2(arm3, seed):
    """Phi = blockdiag(Psi, Psi, Psi), Psi = [psi1; dX + sigma; 1] in R^9, Theta in R^27 (with gravity)."""
    from scipy.linalg import block_diag

    from ilcforce.controllers import nd

    n = arm3.dimension
    controller, meas, JX, ref, mem_prev = _law_inputs(arm3, "c3", seed)
    assert mem_prev.shape[1] == 3 * n * n + 1
    g = arm3.gains["c3"]
    sigma, psi1, psi2, F = _reference_surface_nd(arm3, meas, ref[4], g.psi_acceleration == "desired")
    psi = np.concatenate([psi1, psi2, np.ones(n)])  # eq. (12)
    Phi = block_diag(*([psi[:, None]] * n))  # (3n^2, n), eq. (13)
    gamma = np.concatenate([np.r_[g.gamma[2 * n * i:2 * n * (i + 1)], g.gamma_gravity[n * i:n * (i + 1)]]
                            for i in range(n)])
    theta = mem_prev[4, :3 * n * n] + gamma * (Phi @ sigma)  # eq. (14), Theta update
    alpha = mem_prev[4, 3 * n * n] + g.eta * sigma @ np.sign(sigma)  # eq. (14), alpha update
    u = np.diag(g.k) @ sigma + Phi.T @ theta + arm3.wall.sign * F + alpha * np.sign(sigma)  # eq. (14)
    tau = np.zeros(n)
    mem_new = np.zeros_like(mem_prev)
    type(controller).law(4, 0.0004, meas, ref, controller.gains(), mem_prev, mem_new, True,
                         _diag(controller, n), tau)
    np.testing.assert_allclose(tau, JX.T @ u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mem_new[4], np.r_[theta, alpha], rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("seed", range(3))
def test_sl_adapt_on_three_axes_is_slotine_li(arm3, seed):
    """Slotine & Li eqs. 9.25-9.27 with explicit matrices: dq_r = J_X^-1 (dX + sigma), ddq_r = J_X^-1 (psi1 -
    R dJ dq_r), Y the chain's regressor (chain.py, the readable one) on the base columns, a_hat = a_hat_0 + the
    last change + Ts Gamma Y^T J_X^-1 sigma, tau = Y a_hat + J_X^T (k sigma + w F)."""
    from ilcforce.controllers import nd
    from ilcforce.plants import adaptive, chain

    n = arm3.dimension
    controller, meas, JX, ref, mem_prev = _law_inputs(arm3, "sl-adapt", seed)
    nominal = arm3.plant.nominal()
    columns = adaptive.base_columns(nominal)
    assert mem_prev.shape[1] == len(columns) == len(controller.base_parameter_names)
    g = arm3.gains["sl-adapt"]
    sigma, psi1, psi2, F = _reference_surface_nd(arm3, meas, ref[4], g.psi_acceleration == "desired")
    q = meas[nd.at_py(nd.M_THETA, n):][:n]
    dq = meas[nd.at_py(nd.M_DTHETA, n):][:n]
    p = nominal.as_array()
    R = arm3.wall.frame(n)
    dq_r = np.linalg.solve(JX, psi2)
    ddq_r = np.linalg.solve(JX, psi1 - R @ chain.jacobian_derivative(p, q, dq) @ dq_r)
    Y = chain.slotine_li_regressor(p, q, dq, dq_r, ddq_r)[:, columns]
    a_hat = (controller.initial_estimate() + mem_prev[3]
             + arm3.simulation.sample_time * np.asarray(g.gamma) * (Y.T @ np.linalg.solve(JX, sigma)))
    tau_expected = Y @ a_hat + JX.T @ (np.diag(g.k) @ sigma + arm3.wall.sign * F)
    tau = np.zeros(n)
    mem_new = np.zeros_like(mem_prev)
    mem_new[3] = mem_prev[3]  # this iteration's previous sample's change, which k = 4 steps from
    type(controller).law(4, 0.0004, meas, ref, controller.gains(), mem_prev, mem_new, True, _diag(controller, n),
                         tau)
    np.testing.assert_allclose(tau, tau_expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mem_new[4], a_hat - controller.initial_estimate(), rtol=1e-12, atol=1e-15)


def test_the_api_page_spatial_arm_example_runs(capsys):
    import re

    text = (ROOT / "docs" / "api.md").read_text()
    match = re.search(r"<!-- spatial-arm-example: run by tests/test_ndof.py -->\s*```python\n(.*?)```", text, re.S)
    assert match, "docs/api.md lost its spatial-arm example"
    exec(compile(match.group(1), "docs/api.md", "exec"), {})
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("3 ") and [line.split()[1] for line in lines[-3:]] == ["complete"] * 3


def test_a_law_is_compiled_on_first_use_only():
    """A compiled_law compiles when the law is first read from its class, not when the class is made or the
    registry checks that it has a law (it looks without reading): importing a method loads no kernel."""
    from ilcforce.controllers.nd import compiled_law

    def law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
        return 0

    descriptor = compiled_law(law)
    holder = type("Holder", (), {"law": descriptor})
    assert inspect.getattr_static(holder, "law") is descriptor and descriptor._dispatcher is None
    assert holder.law is descriptor._dispatcher is not None


def _robot_configs():
    yield "fivebar", load_config(None)
    yield "serial2r", load_config(ROOT / "experiments" / "serial2r.toml")
    yield "arm3", load_config(ARM3)


@pytest.mark.parametrize("robot, config", list(_robot_configs()), ids=lambda v: v if isinstance(v, str) else "")
@pytest.mark.parametrize("method", ["c1", "c3", "sl-adapt"])
def test_the_loop_compiled_for_n_equals_the_loop_for_any_n(robot, config, method):
    """The loop is one source compiled per task dimension (n a number: ilcforce.loop.simulate_2, simulate_3) and
    once for any n (simulate_any, n read from the carry): the same arithmetic, so the same numbers, bit for
    bit, over two iterations of learning (C3's implicit scheme, sl-adapt's adaptation within an iteration)."""
    from ilcforce import loop
    from ilcforce.experiment import iteration_inputs

    reference = config.reference_samples()
    runs = {}
    for entry in (loop.simulator(config.dimension), loop.simulator_any()):
        controller = make_controller(config, method)
        records = []
        for j in range(2):
            inputs = iteration_inputs(config, j, reference)
            setup = simulate._setup(inputs, controller)
            setup = dataclasses.replace(setup, simulate_chunk=entry, kernels=(
                controller.law, setup.true_robot.nd_kernel(), setup.nominal_robot.nd_kernel()))
            mem_prev, mem_new = controller.begin_iteration(j)
            record = simulate.run_iteration(dataclasses.replace(inputs, setup=setup), controller, mem_prev, mem_new)
            controller.end_iteration(record)
            records.append(record)
        runs[entry] = records
    specific, generic = runs.values()
    assert loop.simulator(config.dimension) is not loop.simulator_any()
    for a, b in zip(specific, generic):
        assert (a.status, a.fallback_count) == (b.status, b.fallback_count)
        for name, x in a.log.items():
            np.testing.assert_array_equal(x, b.log[name], err_msg=f"{robot} {method} j={a.iteration} {name}")
