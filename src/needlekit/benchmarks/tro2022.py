"""The yardstick of ``needlekit bench control``: the adaptive controller of Marinho and
Adorno (TRO 2022, "Adaptive Constrained Kinematic Control using Partial or Complete
Task-Space Measurements"), whose C++ wheel is on PyPI as
``marinholab-papers-tro2022-adaptivecontrol`` (``pip install 'needlekit[tro2022]'``).

Its own example is rebuilt as the package's README runs it: a 6-DoF VS050 on the wheel's
in-memory reference scene (``SimulatorDummy``), a real and an estimated model whose 36
parameters (base 6, effector 6, 4 DH per link) have the example's confidence bounds, an
estimate drawn inside them that starts clear of the obstacles, 36 VFIs (six spheres on the
links against four walls and two tubes), the example's gains (``MeasureSpace.Pose``,
proportional gain 20, VFI gain 5, VFI weight 0.02, damping 0.01, 0.08 s) and its two
targets ``xd0`` and ``xd1``, 400 steps each. Each call of
``AdaptiveController.compute_setpoint_control_signal`` is timed with ``perf_counter_ns``:
with the adaptation (``FULL``: the task QP and the parameter QP, qpOASES) and without it
(``TASK_ONLY``: the task QP alone, the estimate frozen).

It is a yardstick, not a like-for-like comparison: 6 joints and 36 parameters with qpOASES
in C++ against needlekit's 7 joints and 12 parameters with DAQP in Python.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numpy as np

from needlekit.benchmarks.timing import step_statistics

__all__ = ["TRO2022_PACKAGE", "tro2022_reference"]

TRO2022_PACKAGE = "marinholab-papers-tro2022-adaptivecontrol"

#: The example's confidence bounds (m, deg): base translation and rotation, effector
#: translation and rotation, and each link's d / a and theta / alpha.
_BOUNDS = {"base_m": 0.1, "base_deg": 20.0, "eff_m": 0.01, "eff_deg": 5.0}
_BOUNDS |= {"link_m": 0.001, "link_deg": 1.0}
#: Tool spheres on the six links: their radii (m); each keeps 0.02 m from every wall and tube.
_SPHERE_RADII_M = (0.04, 0.015, 0.015, 0.015, 0.015, 0.075)
_CLEARANCE_M = 0.02


def tro2022_reference(steps_per_target: int = 400, seed: int = 0) -> dict[str, Any]:
    """Time the TRO 2022 wheel's adaptive control step on its own example.

    Parameters
    ----------
    steps_per_target : int
        Control steps towards each of the example's two targets (400 in the example).
    seed : int
        Draws the initial (wrong) parameter estimate.

    Returns
    -------
    dict
        ``status`` (``"measured"``, or ``"skipped"`` with the ``reason``: the package is
        not installed, or does not import beside this ``dqrobotics``), ``version``,
        ``dqrobotics``, and per strategy (``full``: with adaptation, ``task_only``:
        without) the per-call statistics in us.
    """
    record: dict[str, Any] = {"name": "tro2022", "package": TRO2022_PACKAGE}
    try:
        record["version"] = version(TRO2022_PACKAGE)
        record["dqrobotics"] = version("dqrobotics")
    except PackageNotFoundError as exc:
        return record | {
            "status": "skipped",
            "reason": f"{exc.name} is not installed (pip install 'needlekit[tro2022]')",
        }
    try:
        from marinholab.papers.tro2022 import adaptive_control as tro
        from marinholab.papers.tro2022.adaptive_control import _core
    except Exception as exc:  # an ImportError, or a wheel built against another dqrobotics
        return record | {
            "status": "skipped",
            "reason": f"{TRO2022_PACKAGE} {record['version']} does not import beside "
            f"dqrobotics {record['dqrobotics']}: {type(exc).__name__}: {exc}",
        }
    with _cpp_stdout_silenced():  # the wheel's C++ prints to the process's stdout
        example = _Example(tro, _core, np.random.default_rng(seed))
        strategies = tro.Example_AdaptiveControlStrategy
        for key, strategy in (("full", strategies.FULL), ("task_only", strategies.TASK_ONLY)):
            ns, moved = example.run(strategy, steps_per_target)
            record[key] = step_statistics(np.asarray(ns, dtype=float) * 1e-9)
            record[key]["parameter_change"] = moved
    record |= {
        "status": "measured",
        "dof": example.dof,
        "parameters": example.n_parameters,
        "vfis": len(example.vfis),
        "steps_per_target": steps_per_target,
        "sampling_time_s": example.dt,
        "initial_estimate_draws": example.draws,
    }
    return record


@contextlib.contextmanager
def _cpp_stdout_silenced():
    """Send file descriptor 1 to /dev/null for the block (C++ output bypasses sys.stdout)."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


class _Example:
    """The wheel's example: scene, real and estimated VS050, bounds, VFIs, wrong estimate."""

    def __init__(self, tro, core, rng: np.random.Generator) -> None:
        self.tro = tro
        self.params = tro.Example_SimulationParameters(
            tro.MeasureSpace.Pose, 20.0, 5.0, 0.02, 0.01, 0.08, 60.0
        )
        self.dt = float(self.params.sampling_time_sec)
        sim = tro.SimulatorDummy()
        sim.load_reference_scene()
        self.sim = sim
        self.q0 = np.asarray(sim.get_configuration_space_positions(), dtype=float)
        base = sim.get_object_pose("VS050_reference_frame")
        turn = np.cos(-np.pi / 4.0) + tro.i_ * np.sin(-np.pi / 4.0)
        effector = turn + 0.5 * tro.E_ * tro.k_ * 0.15688 * turn
        self.real, self.estimated = (tro.SimulatorDummy.vs050_raw_kinematics() for _ in "ab")
        for robot in (self.real, self.estimated):
            robot.set_base_frame(base)
            robot.set_effector_frame(effector)
            _set_parameter_bounds(robot, core._ParameterSpaceEDH)
        self.dof = int(self.estimated.get_dim_configuration_space())
        self.n_parameters = int(self.estimated.get_dim_parameter_space())
        self.estimated.set_upper_q_dot_limit(np.full(self.dof, 0.1))
        self.estimated.set_lower_q_dot_limit(np.full(self.dof, -0.1))
        self.vfis = self._vfis()
        self.a0, self.draws = self._wrong_estimate(rng)
        self.controller = tro.AdaptiveController(self.estimated, self.params)
        sim.start_simulation()
        self.targets = [sim.get_object_pose("xd0"), sim.get_object_pose("xd1")]

    def _vfis(self) -> list:
        tro, sim, est = self.tro, self.sim, self.estimated
        sim.set_object_pose("x_hat", est.fkm(self.q0))
        for link in range(self.dof):
            sim.set_object_pose(f"tool_sphere_{link + 1}", est.fkm(self.q0, link))
        x_hat = sim.get_object_pose("x_hat")
        vfis = []
        for link, radius in enumerate(_SPHERE_RADII_M):
            sphere = f"tool_sphere_{link + 1}"
            offset = tro.conj(x_hat) * sim.get_object_pose(sphere)
            safe = radius + _CLEARANCE_M
            for k in range(1, 5):
                vfis.append(
                    tro.VFI(f"cube_40x40_wall_{k}", sphere, tro.Primitive.Plane, sim, safe,
                            tro.VFI_Direction.FORBIDDEN_ZONE, 7, offset, "")
                )  # fmt: skip
            for k in (1, 2):
                vfis.append(
                    tro.VFI(f"cube_40x40_tube_{k}", sphere, tro.Primitive.Line, sim, safe**2,
                            tro.VFI_Direction.FORBIDDEN_ZONE, 7, offset, "")
                )  # fmt: skip
        for vfi in vfis:
            vfi.initialize()
        return vfis

    def _wrong_estimate(self, rng: np.random.Generator, max_draws: int = 10000):
        """Parameters drawn in the bounds (towards the middle), clear of every obstacle."""
        lo, hi = (
            np.asarray(b, dtype=float) for b in self.estimated.get_parameter_space_boundaries()
        )
        euclidean = self.tro.VFI_DistanceType.EUCLIDEAN
        for draw in range(1, max_draws + 1):
            w = (rng.random(self.n_parameters) + 1.0) * 0.5
            self.estimated.set_parameter_space_values(w * lo + (1.0 - w) * hi)
            x_hat = self.estimated.fkm(self.q0)
            if all(
                v.get_distance_error(x_hat)
                >= (-1e-3 if v.get_distance_type() == euclidean else -1e-5)
                for v in self.vfis
            ):
                return np.asarray(self.estimated.get_parameter_space_values(), dtype=float), draw
        raise RuntimeError(f"no collision-free initial estimate in {max_draws} draws")

    def run(self, strategy, steps_per_target: int) -> tuple[list[int], float]:
        """The closed loop from the same start; each control call's time (ns) and how far
        the estimate moved."""
        sim, est, real = self.sim, self.estimated, self.real
        q = self.q0.copy()
        sim.set_configuration_space_positions(q)
        a = self.a0.copy()
        est.set_parameter_space_values(a)
        ns: list[int] = []
        for xd in self.targets:
            for _ in range(steps_per_target):
                sim.set_object_pose("x_hat", est.fkm(q))
                y = real.fkm(q)
                sim.set_object_pose("x", y)
                t0 = time.perf_counter_ns()
                uq, ua, *_ = self.controller.compute_setpoint_control_signal(
                    strategy, q, xd, y, self.vfis
                )
                ns.append(time.perf_counter_ns() - t0)
                a = a + np.asarray(ua, dtype=float) * self.dt
                est.set_parameter_space_values(a)
                q = q + np.asarray(uq, dtype=float) * self.dt
                sim.set_configuration_space_positions(q)
        return ns, float(np.linalg.norm(a - self.a0))


def _set_parameter_bounds(robot, space) -> None:
    """The example's confidence interval around every parameter of ``robot``."""
    kind, param = space.Example_ParameterType, space.Example_Parameter
    rad = np.radians
    b = _BOUNDS
    base, eff = robot.get_base_parameters(), robot.get_effector_parameters()
    widths = (b["base_m"],) * 3 + (rad(b["base_deg"]),) * 3
    base_kinds = (
        kind.base_x,
        kind.base_y,
        kind.base_z,
        kind.base_alpha,
        kind.base_beta,
        kind.base_gamma,
    )
    eff_kinds = (kind.eff_x, kind.eff_y, kind.eff_z, kind.eff_alpha, kind.eff_beta, kind.eff_gamma)
    eff_widths = (b["eff_m"],) * 3 + (rad(b["eff_deg"]),) * 3
    out = [
        param(-1, k, p.value_, p.value_ - w, p.value_ + w)
        for k, p, w in zip(base_kinds, base, widths, strict=True)
    ]
    link = (
        (kind.theta, robot.get_theta, rad(b["link_deg"])),
        (kind.d, robot.get_d, b["link_m"]),
        (kind.a, robot.get_a, b["link_m"]),
        (kind.alpha, robot.get_alpha, rad(b["link_deg"])),
    )
    for i in range(robot.get_dim_configuration_space()):
        out += [param(i, k, get(i), get(i) - w, get(i) + w) for k, get, w in link]
    n = robot.get_dim_configuration_space()
    out += [
        param(n, k, p.value_, p.value_ - w, p.value_ + w)
        for k, p, w in zip(eff_kinds, eff, eff_widths, strict=True)
    ]
    robot.set_parameter_space(out)
