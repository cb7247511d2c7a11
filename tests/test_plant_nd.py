"""The n-joint plant kernels (``ilcforce.plants.nd``): one ``nd_dyn`` per plant that an n-joint loop calls.

What is checked, and against what:

* The layout: the offsets are the interface's table for every n; importing the interface imports no numba.
* The chain's allocation-free kernel (``ilcforce.plants.chain_nd``) against the readable reference
  (``ilcforce.plants.chain``) and against MuJoCo, on 1,000 random states of each shipped model
  (arm3.xml, serial2r.xml) and of test_model_file's random 4-link chain, per level: each level writes
  its entries and leaves the higher levels' untouched. The bar is 1e-12 relative: both sides are the
  same float64 recursions in another order (1e-15 seen), where a wrong term is O(1).
* No allocation: 1e5 calls through a function pointer inside a compiled loop leave numba's
  allocation counters where the loop's own boxing puts them (and a loop that allocates is seen).
* The 2-joint plants' kernels (five-bar, serial 2R, planar arm from a file): every entry is the
  DYN kernel's own, bit for bit.
* The arm's inverse kinematics: a round trip to 1e-12 m, and one line when it cannot.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from test_model_file import MODELS, Library, _relative, random_chain_mjcf  # noqa: E402

from ilcforce.plants import UnreachableError, chain, chain_nd, load_model, make_plant, nd  # noqa: E402

STATES = 1000
#: the kernel against chain.py and MuJoCo: the same exact algorithms summed in another order
RTOL = 1e-12


@pytest.fixture(scope="module")
def random_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("chain") / "random4.xml"
    path.write_text(random_chain_mjcf(37), encoding="utf-8")
    return path


CHAINS = {"arm3.xml": (MODELS / "arm3.xml", "tool"), "serial2r.xml": (MODELS / "serial2r.xml", "tool"),
          "random4": (None, "tcp")}


def _chain(name, random_file):
    path, ee = CHAINS[name]
    path = random_file if path is None else path
    return path, ee, load_model(path, ee)


# --- the layout ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 3, 4, 7])
def test_the_offsets_are_the_interfaces(n):
    o = nd.offsets(n)
    assert o == (0, n, n + n * n, 2 * n + n * n, 2 * n + 2 * n * n, 3 * n + 2 * n * n, 3 * n + 3 * n * n,
                 4 * n + 3 * n * n, 4 * n + 4 * n * n)
    assert nd.offsets(n, 3).width == 2 * 3 + 2 * 3 * n + 2 * n + 2 * n * n
    assert nd.nd_layout(n, n) == tuple(o)  # the compiled copy


def test_importing_the_interface_imports_no_numba():
    code = ("import sys\nimport ilcforce.plants.nd, ilcforce.plants.chain_nd, ilcforce.plants.serial_arm\n"
            "print('NUMBA', 'numba' in sys.modules)")
    # timeout: a hang guard for a ~1 s import (no bound on speed)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "ILCFORCE_AOT": "0"})
    assert proc.returncode == 0, proc.stderr
    assert "NUMBA False" in proc.stdout, proc.stdout


# --- the chain's kernel ----------------------------------------------------------------------------------

def _read(out, n, task=3):
    """The entries of ``out`` by name, as arrays shaped as chain.py returns them."""
    o = nd.offsets(n, task)
    return {"P": out[o.p:o.p + task], "J": out[o.j:o.j + task * n].reshape(task, n),
            "dJ dq": out[o.djv:o.djv + task], "M": out[o.m:o.m + n * n].reshape(n, n), "b": out[o.b:o.b + n],
            "C": out[o.cq:o.cq + n * n].reshape(n, n), "g": out[o.g:o.g + n],
            "dJ": out[o.dj:o.dj + task * n].reshape(task, n)}


#: the entries each level writes (and the ones below it)
LEVEL_ENTRIES = {0: ("P", "J"), 1: ("dJ dq", "M", "b"), 2: ("C", "g", "dJ")}


def _states(n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(STATES):
        yield rng.uniform(-math.pi, math.pi, n), rng.uniform(-3.0, 3.0, n)


@pytest.mark.parametrize("name", list(CHAINS))
def test_the_chain_kernel_equals_chain_py_and_mujoco(name, random_file):
    path, ee, arm = _chain(name, random_file)
    n, p = arm.n, arm.packed
    kernel = chain_nd.kernel()
    library = Library(path, ee, arm.gravity_vector)
    zero = np.zeros(n)
    worst: dict[str, float] = {}
    written = {0: LEVEL_ENTRIES[0], 1: LEVEL_ENTRIES[0] + LEVEL_ENTRIES[1],
               2: LEVEL_ENTRIES[0] + LEVEL_ENTRIES[1] + LEVEL_ENTRIES[2]}
    for q, dq in _states(n, seed=len(name)):
        dJ = chain.jacobian_derivative(p, q, dq)
        reference = {"P": chain.forward_kinematics(p, q), "J": chain.jacobian(p, q), "dJ dq": dJ @ dq,
                     "M": chain.joint_inertia(p, q), "b": chain.inverse_dynamics(p, q, dq, zero, True),
                     "C": chain.joint_coriolis(p, q, dq), "g": chain.inverse_dynamics(p, q, zero, zero, True), "dJ": dJ}
        lib = library.at(q, dq, zero)
        lib_g = library.at(q, zero, zero)["bias"]
        library_values = {"P": lib["P"], "J": lib["J"], "dJ dq": lib["dJ"] @ dq, "M": lib["M"], "b": lib["bias"],
                          "g": lib_g, "dJ": lib["dJ"]}
        for level in (0, 1, 2):
            out = np.full(chain_nd.width(n), np.nan)
            assert kernel(arm.address, q, dq, level, out) == 1.0
            ours = _read(out, n)
            for key, value in ours.items():
                if key not in written[level]:
                    assert np.isnan(value).all(), f"{name}: level {level} wrote {key}"
                    continue
                worst[f"{key} chain.py"] = max(worst.get(f"{key} chain.py", 0.0), _relative(value, reference[key]))
                if key in library_values:
                    worst[f"{key} MuJoCo"] = max(worst.get(f"{key} MuJoCo", 0.0), _relative(value, library_values[key]))
            if level == 2:  # C itself against MuJoCo: C dq + g is MuJoCo's bias
                worst["C dq + g MuJoCo"] = max(worst.get("C dq + g MuJoCo", 0.0),
                                               _relative(ours["C"] @ dq + ours["g"], lib["bias"]))
    print(name, {k: f"{v:.1e}" for k, v in worst.items()})
    bad = {k: v for k, v in worst.items() if v > RTOL}
    assert not bad, f"{name}: relative errors over {RTOL}: {bad}"


@pytest.fixture(scope="module")
def counting_loops():
    """(loop, allocating_loop): compiled loops calling an nd_dyn through a function pointer ``calls``
    times; the second also allocates one array per call (the check must see it)."""
    from ilcforce.compiled import jit

    nb = jit.numba()
    vector = nb.types.Array(nb.types.float64, 1, "C")
    signature = (nd.nd_type(), nb.types.intp, vector, vector, nb.types.int64, vector, nb.types.int64)

    @nb.njit(signature, cache=False)
    def loop(kernel, address, q, dq, level, out, calls):
        total = 0.0
        for _ in range(calls):
            q[0] += 1e-9
            total += kernel(address, q, dq, level, out)
        return total

    @nb.njit(signature, cache=False)
    def allocating_loop(kernel, address, q, dq, level, out, calls):
        total = 0.0
        for _ in range(calls):
            q[0] += 1e-9
            total += kernel(address, q, dq, level, out) + np.empty(1).size
        return total

    return loop, allocating_loop


def _allocations(loop, kernel, address, n, width, level, calls):
    """numba's allocation counters' growth over one call of ``loop``."""
    from numba.core.runtime import _nrt_python, rtsys

    was = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        q, dq, out = np.full(n, 0.3), np.full(n, 0.5), np.zeros(width)
        before = rtsys.get_allocation_stats()
        loop(kernel, address, q, dq, level, out, calls)
        after = rtsys.get_allocation_stats()
    finally:
        if not was:
            _nrt_python.memsys_disable_stats()
    return tuple(a - b for a, b in zip(after, before))


@pytest.mark.parametrize("level", [0, 1, 2])
def test_the_chain_kernel_allocates_nothing(level, counting_loops):
    loop, allocating_loop = counting_loops
    arm = load_model(MODELS / "arm3.xml", "tool")
    args = (arm.nd_kernel(), arm.address, arm.n, arm.nd_width, level)
    boxing = _allocations(loop, *args, calls=0)  # the loop's arguments, unboxed from Python
    assert _allocations(loop, *args, calls=100_000) == boxing
    assert _allocations(allocating_loop, *args, calls=1000)[0] >= boxing[0] + 1000  # the check sees an allocation


# --- Slotine-Li's regressor (sl-adapt's n-axis law) -----------------------------------------------------

@pytest.mark.parametrize("name", list(CHAINS))
def test_the_slotine_li_regressor_is_m_c_g_with_the_christoffel_c(name, random_file):
    """chain.slotine_li_regressor(q, dq, dq_r, ddq_r) pi = M ddq_r + C(q, dq) dq_r + g with C the Christoffel
    matrix (so dM/dt - 2 C is skew, Slotine & Li's premise), checked against M, C and g from the composite
    inertias and dM/dq and against MuJoCo's inverse dynamics (at dq_r = dq); the kernel's allocation-free copy
    (chain_nd.slotine_li_regressor) and dJ/dt x (chain_nd.jacobian_rate_times) equal chain.py's; and the base
    columns' dependencies (Y_D = Y_B beta, found on dq_r = dq) hold for every dq_r. Measured: 1e-16 to 1e-14, the
    base columns to beta's precision."""
    path, ee, arm = _chain(name, random_file)
    n, p = arm.n, arm.packed
    pi = chain.inertial_parameters(p).ravel()
    columns, beta = chain.base_columns(p)
    others = [c for c in range(pi.size) if c not in columns]
    library = Library(path, ee, arm.gravity_vector)
    rng = np.random.default_rng(11 + n)
    work = np.full(chain_nd.width(n), np.nan)
    Y_nd = np.full(3 + n * pi.size, np.nan)
    worst: dict[str, float] = {}

    def note(key, value, reference):
        worst[key] = max(worst.get(key, 0.0), _relative(value, reference))

    for q, dq in _states(n, seed=2 * n):
        dq_r, ddq_r = rng.uniform(-3.0, 3.0, n), rng.uniform(-5.0, 5.0, n)
        Y = chain.slotine_li_regressor(p, q, dq, dq_r, ddq_r)
        M, C = chain.joint_inertia(p, q), chain.joint_coriolis(p, q, dq)
        g = chain.inverse_dynamics(p, q, np.zeros(n), np.zeros(n), True)
        note("Y pi = M ddq_r + C dq_r + g", Y @ pi, M @ ddq_r + C @ dq_r + g)
        note("Y(dq_r = dq) pi = MuJoCo", chain.slotine_li_regressor(p, q, dq, dq, ddq_r) @ pi,
             library.at(q, dq, ddq_r)["tau"])
        note("base columns", Y[:, others], Y[:, columns] @ beta)
        Y_id = chain.regressor(p, q, dq, ddq_r)  # the motion base_columns found its columns on
        note("base columns at dq_r = dq", Y_id[:, others], Y_id[:, columns] @ beta)
        chain_nd.terms(p, q, dq, 0, work)
        chain_nd.slotine_li_regressor(p, dq, dq_r, ddq_r, work, Y_nd, 3)
        note("chain_nd Y", Y_nd[3:].reshape(n, -1), Y)
        note("chain_nd dJ x", np.array(chain_nd.jacobian_rate_times(p, dq, dq_r, work)),
             chain.jacobian_derivative(p, q, dq) @ dq_r)
        skew = np.einsum("kij,k->ij", chain.inertia_gradient(p, q), dq) - 2 * C  # dM/dt - 2 C
        worst["dM/dt - 2 C skew"] = max(worst.get("dM/dt - 2 C skew", 0.0),
                                        np.abs(skew + skew.T).max() / np.abs(skew).max())
    print(name, {k: f"{v:.1e}" for k, v in worst.items()})
    # beta is a least-squares fit (random4's has entries up to 1e4): the dependencies hold to its precision,
    # 7e-12 on random4 at dq_r = dq itself; for any dq_r they must hold as well (Newton-Euler's own C, not
    # symmetrised, misses them by 0.2)
    fit = max(RTOL, 10 * worst.pop("base columns at dq_r = dq"))
    assert worst.pop("base columns") < fit, name
    bad = {k: v for k, v in worst.items() if v > RTOL}
    assert not bad, f"{name}: relative errors over {RTOL}: {bad}"


# --- the 2-joint plants --------------------------------------------------------------------------------

def _two_joint_plants():
    from ilcforce.config_load import load_config

    return {name: make_plant(load_config(f"experiments/{name}").plant.nominal())
            for name in ("paper.toml", "serial2r.toml", "serial2r-model.toml")}


def _bits(values):
    return np.asarray(values, dtype=np.float64).view(np.uint64)


@pytest.mark.parametrize("experiment", ["paper.toml", "serial2r.toml", "serial2r-model.toml"])
def test_a_two_joint_plants_kernel_is_its_dyn_kernel_bit_for_bit(experiment):
    plant = _two_joint_plants()[experiment]
    kernel, dyn = plant.nd_kernel(), plant.kernels().dyn
    assert plant.nd_width == nd.offsets(2).width == 24
    rng = np.random.default_rng(3)
    inside = 0
    for _ in range(STATES):
        q, dq = rng.uniform(-math.pi, math.pi, 2), rng.uniform(-3.0, 3.0, 2)
        t = dyn(plant.address, q[0], q[1], dq[0], dq[1])
        for level in (0, 1, 2):
            out = np.full(plant.nd_width, np.nan)
            ok = kernel(plant.address, q, dq, level, out)
            assert ok == t[0]
            if not ok:
                continue
            d1, d2 = dq
            expected = [*t[1:7]]  # P, J
            if level >= 1:  # dJ dq, M (Dq01 both ways), b = Cq dq + G_q
                expected += [t[7] * d1 + t[8] * d2, t[9] * d1 + t[10] * d2, t[11], t[12], t[12], t[13],
                             t[14] * d1 + t[15] * d2 + t[18], t[16] * d1 + t[17] * d2 + t[19]]
            if level >= 2:  # Cq, G_q, dJ
                expected += [*t[14:18], t[18], t[19], *t[7:11]]
            np.testing.assert_array_equal(_bits(out[:len(expected)]), _bits(expected),
                                          err_msg=f"{experiment} level {level} at q = {q}, dq = {dq}")
            assert np.isnan(out[len(expected):]).all(), f"{experiment}: level {level} wrote past its entries"
        inside += bool(t[0])
    assert inside > STATES // 4, f"{experiment}: only {inside} of {STATES} random states in the working mode"


# --- the arm as the n-joint loop's plant ------------------------------------------------------------------

def test_the_arms_interface():
    arm = load_model(MODELS / "arm3.xml", "tool")
    assert arm.address == arm.packed.ctypes.data
    assert arm.nd_width == nd.offsets(3).width + chain_nd.scratch(3) == 48 + chain_nd.scratch(3)
    assert arm.nd_kernel() is chain_nd.kernel()
    with pytest.raises(ValueError, match=r"as many joints as task dimensions \(3\); this arm has 2"):
        load_model(MODELS / "serial2r.xml", "tool").nd_kernel()


def test_inverse_kinematics_round_trip():
    arm = load_model(MODELS / "arm3.xml", "tool")
    rng = np.random.default_rng(11)
    for _ in range(50):
        q = rng.uniform([-math.pi, -1.2, 0.3], [math.pi, 1.2, 2.5])
        target = arm.forward_kinematics(q)
        found = arm.inverse_kinematics(target, q + rng.uniform(-0.2, 0.2, 3))
        assert np.linalg.norm(arm.forward_kinematics(found) - target) <= 1e-12


def _one_line(excinfo):
    text = str(excinfo.value)
    assert "\n" not in text and text, text
    return text


def test_inverse_kinematics_refuses_in_one_line():
    arm = load_model(MODELS / "arm3.xml", "tool")
    with pytest.raises(UnreachableError) as far:
        arm.inverse_kinematics([3.0, 0.0, 0.5], [0.0, 0.5, 1.0])
    assert "not reachable" in _one_line(far)
    # a pose with the end effector on the base's yaw axis: the yaw joint cannot move it (J singular)
    q = np.array([0.0, 0.0, 1.0])
    lo, hi = -math.pi / 2, math.pi / 2
    x = lambda s: arm.forward_kinematics([0.0, s, 1.0])[0]  # noqa: E731
    assert x(lo) * x(hi) < 0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if x(lo) * x(mid) > 0 else (lo, mid)
    q[1] = 0.5 * (lo + hi)
    target = arm.forward_kinematics(q)
    assert math.hypot(target[0], target[1]) < 1e-12
    with pytest.raises(UnreachableError) as singular:
        arm.inverse_kinematics(target, q)
    assert "singular" in _one_line(singular)
    with pytest.raises(ValueError, match=r"position must have shape \(3,\)"):
        arm.inverse_kinematics([0.1, 0.2], q)
