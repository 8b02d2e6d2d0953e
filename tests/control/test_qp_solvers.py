"""The QP solver adapter: every registered solver on analytic QPs, infeasible and crossed
bounds, the registry (names, objects, a user's solver, entry points), and DAQP against
quadprog on the controller's own QPs over 10 seeded trials, tick by tick."""

import dataclasses
import sys
from importlib import metadata

import numpy as np
import pytest

from needlekit.control import qp_registry
from needlekit.control.controller import ControllerSettings, GuideLine, Step, control_step
from needlekit.control.panda import PandaModel
from needlekit.control.procedure import run_trial
from needlekit.control.qp import NO_BOUND, DAQPSolver, QPSolver, QPStatus, solve_qp
from needlekit.control.qp_registry import (
    get_qp_solver,
    qp_solver_names,
    register_qp_solver,
    unregister_qp_solver,
)
from needlekit.errors import InvalidInputError, NeedlekitError
from needlekit.studies.puncture_study import PunctureScenario, TrialOptions, sample_trial
from needlekit.studies.puncture_study import trial_settings as study_trial_settings

NO_QUADPROG = "quadprog is not installed: pip install 'needlekit[quadprog]' (make test does)"


def _quadprog():
    pytest.importorskip("quadprog", reason=NO_QUADPROG)
    return get_qp_solver("quadprog")


@pytest.fixture(params=["daqp", "quadprog"])
def solver(request):
    return get_qp_solver("daqp") if request.param == "daqp" else _quadprog()


def test_the_default_solver_is_daqp_and_both_are_listed():
    assert isinstance(get_qp_solver(), DAQPSolver) and get_qp_solver("daqp") is get_qp_solver()
    assert qp_solver_names()[:2] == ["daqp", "quadprog"]


def test_an_analytic_qp_with_rows_and_bounds(solver):
    # min 1/2 |x|^2 - (1, 2) x  s.t.  x0 + x1 <= 1,  x0 >= 0.25: the projection of (1, 2)
    # onto the half-plane is (0, 1), which x0 >= 0.25 moves to (0.25, 0.75)
    H, f = np.eye(2), np.array([-1.0, -2.0])
    A = np.array([[1.0, 1.0]])
    upper = np.array([NO_BOUND, NO_BOUND, 1.0])
    lower = np.array([0.25, -NO_BOUND, -NO_BOUND])
    s = solver.solve(H, f, A, upper, lower)
    assert s.status is QPStatus.OPTIMAL and s.exitflag >= 1
    np.testing.assert_allclose(s.x, [0.25, 0.75], atol=solver.tolerance)


def test_lower_bounds_on_rows_and_equalities(solver):
    # min 1/2 |x|^2  s.t.  x0 + x1 >= 2 (a row's lower bound),  x0 - x1 == 0.5 (l == u)
    H, f = np.eye(2), np.zeros(2)
    A = np.array([[1.0, 1.0], [1.0, -1.0]])
    upper = np.array([NO_BOUND, NO_BOUND, NO_BOUND, 0.5])
    lower = np.array([-NO_BOUND, -NO_BOUND, 2.0, 0.5])
    s = solver.solve(H, f, A, upper, lower)
    assert s.status is QPStatus.OPTIMAL
    np.testing.assert_allclose(s.x, [1.25, 0.75], atol=solver.tolerance)


def test_no_constraints_at_all(solver):
    s = solver.solve(2.0 * np.eye(3), np.array([2.0, -4.0, 6.0]), np.zeros((0, 3)),
                     np.full(3, NO_BOUND), np.full(3, -NO_BOUND))  # fmt: skip
    np.testing.assert_allclose(s.x, [-1.0, 2.0, -3.0], atol=solver.tolerance)


def test_an_infeasible_qp_says_so_and_returns_no_x(solver):
    # x0 <= -1 and x0 >= 1 as two rows
    A = np.array([[1.0, 0.0], [-1.0, 0.0]])
    upper = np.array([NO_BOUND, NO_BOUND, -1.0, -1.0])
    lower = np.full(4, -NO_BOUND)
    s = solver.solve(np.eye(2), np.zeros(2), A, upper, lower)
    assert s.status is QPStatus.INFEASIBLE and s.x is None and s.exitflag == -1
    crossed = solver.solve(np.eye(2), np.zeros(2), np.zeros((0, 2)), np.array([0.0, 1.0]),
                           np.array([1.0, 0.0]))  # fmt: skip
    assert crossed.status is QPStatus.INFEASIBLE and crossed.x is None


@pytest.mark.parametrize("seed", range(20))
def test_the_two_solvers_agree_on_random_qps(seed):
    quadprog = _quadprog()
    rng = np.random.default_rng(seed)
    n, m = 7, 5
    M = rng.normal(size=(9, n))
    H, f = M.T @ M + 1e-3 * np.eye(n), rng.normal(size=n) * 3
    A = rng.normal(size=(m, n))
    upper = np.concatenate([np.full(n, 0.5), rng.uniform(0.1, 1.0, m)])
    lower = np.concatenate([np.full(n, -0.5), np.full(m, -NO_BOUND)])
    a, b = (s.solve(H, f, A, upper, lower) for s in (get_qp_solver("daqp"), quadprog))
    assert a.status is b.status is QPStatus.OPTIMAL
    np.testing.assert_allclose(a.x, b.x, atol=1e-6)
    s = solve_qp(H, f, A, upper[n:], lower[:n], upper[:n], solver=quadprog)
    np.testing.assert_allclose(s.x, b.x, atol=1e-12)


def test_an_unknown_name_lists_the_solvers():
    with pytest.raises(InvalidInputError, match=r"^qp_solver: unknown QP solver 'osqp'; "
                       r"available: daqp, quadprog"):  # fmt: skip
        get_qp_solver("osqp")
    with pytest.raises(InvalidInputError, match=r"^qp_solver: expected a solver name"):
        get_qp_solver(42)


def test_a_missing_extra_says_which_to_install(monkeypatch):
    from needlekit.control.qp_quadprog import QuadprogSolver

    monkeypatch.setitem(sys.modules, "quadprog", None)  # the import fails
    with pytest.raises(NeedlekitError, match=r"pip install 'needlekit\[quadprog\]'"):
        QuadprogSolver()


class _Counting(QPSolver):
    """A user's solver: DAQP underneath, counting its calls."""

    name = "counting"

    def __init__(self):
        self.calls = 0
        self._daqp = DAQPSolver()

    def solve(self, H, f, A, upper, lower):
        self.calls += 1
        return self._daqp.solve(H, f, A, upper, lower)


def test_a_users_solver_plugs_in_by_name_without_edits():
    register_qp_solver("counting", _Counting)
    try:
        with pytest.raises(InvalidInputError, match="already registered"):
            register_qp_solver("counting", DAQPSolver)
        mine = get_qp_solver("counting")
        model = PandaModel()
        guide = GuideLine(np.array([-150.0, 0.0, -250.0]), np.array([0.0, 0.0, 1.0]))
        q = np.array(PunctureScenario().q0)
        out = control_step(model, q, Step.ALIGN, guide, solver="counting")
        ref = control_step(model, q, Step.ALIGN, guide)
        assert mine.calls == 1 and np.array_equal(out.q_dot, ref.q_dot)
    finally:
        unregister_qp_solver("counting")
    assert "counting" not in qp_solver_names()


def test_an_entry_point_adds_a_solver(monkeypatch):
    class _EP:
        name, value = "from_plugin", "plugin:Solver"

        def load(self):
            return _Counting

    monkeypatch.setattr(metadata, "entry_points", lambda group: [_EP()] if
                        group == qp_registry.ENTRY_POINT_GROUP else [])  # fmt: skip
    monkeypatch.setattr(qp_registry, "_ENTRY_POINTS_LOADED", False)
    try:
        assert "from_plugin" in qp_solver_names()
        assert isinstance(get_qp_solver("from_plugin"), _Counting)
    finally:
        unregister_qp_solver("from_plugin")


class _Shadow(QPSolver):
    """DAQP drives the loop; quadprog solves every same QP beside it (the arrays are the
    kernels' buffers, so both see the identical problem)."""

    name = "shadow"

    def __init__(self, other):
        self.daqp, self.other = DAQPSolver(), other
        self.max_diff = 0.0
        self.compared = self.status_mismatch = 0
        self.sizes = set()

    def solve(self, H, f, A, upper, lower):
        a = self.daqp.solve(H, f, A, upper, lower)
        b = self.other.solve(H, f, A, upper, lower)
        self.status_mismatch += a.status is not b.status
        if a.status is QPStatus.OPTIMAL and b.status is QPStatus.OPTIMAL:
            self.compared += 1
            self.sizes.add(f.shape[0])
            self.max_diff = max(self.max_diff, float(np.max(np.abs(a.x - b.x))))
        return a


class _Recording(QPSolver):
    """A solver that records every solution it returns (the joint velocities, tick by tick,
    and the adaptation's rates)."""

    def __init__(self, inner):
        self.inner, self.name, self.xs = inner, inner.name, []

    def solve(self, H, f, A, upper, lower):
        s = self.inner.solve(H, f, A, upper, lower)
        self.xs.append(None if s.x is None else s.x.copy())
        return s


def _short_trials(n=10, timeout_s=3.0):
    """The first ``n`` study trials, each cut short (an iteration budget: the initial
    adaptation, then the alignment until its phase limit)."""
    scenario = PunctureScenario()
    for index in range(n):
        setup, _ = sample_trial(scenario, np.random.default_rng(index), index)
        adaptation, ps, spec = study_trial_settings(
            scenario, TrialOptions(), setup.nominal_parameters
        )
        ps = dataclasses.replace(ps, phase_timeout_s=timeout_s)
        yield index, setup, adaptation, ps, spec


# DAQP accepts a point whose constraint rows are violated by up to its primal tolerance
# (1e-6); quadprog solves its active set's KKT system exactly. Where the two end on the same
# active set their x differ by rounding (~1e-12 here); 1e-6 rad/s (and 1e-6 of the
# adaptation's rates) is DAQP's tolerance: a joint velocity error of 1e-9 rad per 1 ms tick.
TICK_ATOL = 1e-6


@pytest.mark.slow
def test_ten_trials_daqp_and_quadprog_give_the_same_joint_velocities_tick_by_tick():
    quadprog = _quadprog()
    shadow = _Shadow(quadprog)
    for index, setup, adaptation, ps, spec in _short_trials():
        # closed loop, each solver on its own; beside DAQP's run quadprog solves each of
        # DAQP's QPs too (the same problem: a difference is only the solvers')
        runs = []
        for inner in (shadow, quadprog):
            rec = _Recording(inner)
            r = run_trial(
                setup, np.random.default_rng(100 + index), adaptation=adaptation,
                procedure=dataclasses.replace(ps, qp_solver=rec), needle_sensor=spec,
                scope_sensor=spec,
            )  # fmt: skip
            runs.append((r, rec.xs))
        (ra, xa), (rb, xb) = runs
        assert ra.phase_times_s.keys() == rb.phase_times_s.keys() and ra.counts == rb.counts
        assert len(xa) == len(xb) > 0
        for a, b in zip(xa, xb, strict=True):
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_allclose(a, b, rtol=0, atol=TICK_ATOL)
        np.testing.assert_allclose(ra.log["tip_mm"], rb.log["tip_mm"], rtol=0, atol=1e-6)
    assert shadow.status_mismatch == 0
    assert shadow.compared > 10_000 and shadow.sizes == {7, 12}  # controller and adaptation
    assert shadow.max_diff <= TICK_ATOL


# Off the trials' paths (random states, the tip far from the guide line: rows of norm
# ~1e5) the QP is nearly flat along two joint-space directions (H's smallest eigenvalues
# are 2 damping^2 = 2e-6), and each solver stops within its own tolerance (quadprog's rows
# within ~1e-6 of their bounds at that scale, DAQP's cost within ~1e-6 of the optimum): a
# cost difference dJ moves x along them by up to sqrt(2 dJ / 2e-6), measured up to 3e-5.
# 1e-4 rad/s is 1e-7 rad in a 1 ms tick.
FLAT_ATOL = 1e-4


def test_a_puncture_step_is_the_same_with_either_solver():
    quadprog = _quadprog()
    model = PandaModel()
    rng = np.random.default_rng(3)
    guide = GuideLine(np.array([-150.0, 0.0, -250.0]), np.array([0.3, 0.2, 0.93]))
    q0 = np.array(PunctureScenario().q0)
    for _ in range(20):
        q = q0 + rng.normal(scale=0.05, size=7)
        tip = model.state(q).tip_mm
        kw = {"desired_mm": tip + rng.normal(size=3), "desired_velocity_mm_s": np.zeros(3)}
        a = control_step(model, q, Step.PUNCTURE, guide, ControllerSettings(), **kw)
        b = control_step(model, q, Step.PUNCTURE, guide, ControllerSettings(), solver=quadprog,
                         **kw)  # fmt: skip
        assert a.status is b.status
        np.testing.assert_allclose(a.q_dot, b.q_dot, rtol=0, atol=FLAT_ATOL)


def test_the_commands_refuse_an_unknown_solver_in_one_line(capsys, tmp_path):
    from needlekit.cli import main

    for argv in (["puncture", "--trials", "1", "--out", str(tmp_path), "--qp-solver", "osqp"],
                 ["bench", "control", "--qp-solver", "osqp"]):  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["error: --qp-solver: unknown QP solver 'osqp'; available: daqp, quadprog"]


def test_the_docs_example_of_adding_a_solver_runs(capsys):
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "control.md").read_text()
    block = text.split("A\nsolver built on scipy's SLSQP", 1)[1].split("```python\n", 1)[1]
    code = block.split("```", 1)[0]
    try:
        exec(compile(code, "docs/control.md", "exec"), {})
        assert capsys.readouterr().out.strip() == "optimal [0. 1.]"
    finally:
        unregister_qp_solver("slsqp")
