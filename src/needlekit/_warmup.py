"""Compile needlekit's planning and control kernels ahead of use: ``python -m needlekit._warmup``.

numba compiles a kernel the first time it runs and keeps the machine code in its cache
(``cache=True``), so every later process loads it in milliseconds. ``make install`` (and so
``make demo`` and ``make test``) runs this once, so that a user's first ``needlekit plan``
does not spend seconds compiling. Planners also warm up before their clock starts
(:func:`needlekit.planning.steerable.search.warm_up`), so budgets hold either way; this only
moves the one-time cost to installation.
"""

from __future__ import annotations

import concurrent.futures
import importlib
import multiprocessing
import os
import time

import numpy as np

__all__ = ["warm_up_kernels"]


def warm_up_kernels(jobs: int | None = None) -> float:
    """Plan once with every steerable planner on two tiny problems (the ``field`` model
    over analytic shapes and a voxel grid, and the ``voxel_centres`` model), two straight
    needles, run the puncture controller's steps and adaptation (:func:`_warm_up_control`),
    insert a needle by its mechanics (:func:`_warm_up_mechanics`) and build and read
    anatomy: the phantoms, a mesh, masks (:func:`_warm_up_anatomy`).

    Parameters
    ----------
    jobs : int, optional
        Processes to share the work (default: 2 where the machine has two cores or more).
        Five parts (anatomy, steerable planners, controller, straight planner, mechanics)
        go to them, longest first; numba's cache on disk is where they leave the kernels.

    Returns
    -------
    float
        Seconds it took.
    """
    t0 = time.perf_counter()
    if jobs is None:
        jobs = 2 if (os.cpu_count() or 1) >= 2 else 1
    # longest first: on two processes the anatomy (about 34 s cold) runs beside the
    # steerable planners (20 s) and then the controller (17 s), the straight planner
    # (11 s) after it
    groups = (_warm_up_anatomy, _warm_up_steerable, _warm_up_control, _warm_up_straight_vessel,
              _warm_up_mechanics)  # fmt: skip
    if jobs <= 1:
        for group in groups:
            group()
    else:
        ctx = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=ctx) as pool:
            for done in [pool.submit(group) for group in groups]:
                done.result()
    return time.perf_counter() - t0


def _vessel_grid():
    """A vessel along z in a 1 mm grid (occupancy and affine)."""
    idx = np.arange(-20, 21)
    grid = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1).astype(float)
    tube = np.hypot(grid[..., 0] - 6.0, grid[..., 1]) <= 2.0
    affine = np.eye(4)
    affine[:3, 3] = -20.0
    return tube, affine


def _warm_up_steerable() -> None:
    """Each steerable planner on the ``field`` and the ``voxel_centres`` models (writable
    and read-only occupancy)."""
    from needlekit.anatomy.occupancy import VoxelObstacles
    from needlekit.anatomy.primitives import Capsule, Sphere
    from needlekit.anatomy.scene import Role, Scene, Structure
    from needlekit.anatomy.voxel import VoxelSDF
    from needlekit.planning.steerable.problem import SteerableProblem
    from needlekit.planning.steerable.solve import solve

    tube, affine = _vessel_grid()
    scene = Scene(
        [
            Structure("body", Role.ALLOWED_REGION, Sphere([0.0, 0.0, 0.0], 60.0)),
            Structure("vessel", Role.OBSTACLE, VoxelSDF.from_mask(tube, affine)),
            Structure("airway", Role.OBSTACLE, Capsule([-9, 0, -20], [-9, 0, 20], 2.0)),
        ]
    )
    start = np.eye(4)
    start[:3, 3] = [0.0, 0.0, -15.0]
    field = SteerableProblem(scene, goal_mm=[0.0, 0.0, 15.0], start_pose=start)
    # VoxelObstacles holds read-only views of any occupancy: one kernel type for all
    problems = [
        field,
        SteerableProblem(
            scene,
            goal_mm=[0.0, 0.0, 15.0],
            start_pose=start,
            collision_model="voxel_centres",
            voxel_obstacles=VoxelObstacles(tube, affine, needle_diameter_mm=1.0),
        ),
    ]
    for problem in problems:
        for planner in ("rcs_star", "rcs", "rrt"):
            solve(problem, planner, time_limit_s=60.0, max_iterations=20)


def _warm_up_anatomy() -> None:
    """What building and reading anatomy compiles: the phantoms' shape kernels (coarse
    grids, the same argument types as the default 1 mm ones), their fields' trilinear
    kernels, a mesh's winding numbers and voxelised distance, an ellipsoid, the mask
    reader's binarisation of each integer type Med-RAD and NIfTI files use, and the
    voxel model's clearance and finer connectivity proof."""
    from needlekit.anatomy.collision import VoxelCentresChecker  # noqa: F401 - its kernels
    from needlekit.anatomy.mesh import ExactMeshDistance, voxelize_mesh_sdf
    from needlekit.anatomy.occupancy import VoxelObstacles
    from needlekit.anatomy.phantoms import make_phantom
    from needlekit.anatomy.primitives import Ellipsoid
    from needlekit.anatomy.voxel_clearance import nearest_obstacle_distance
    from needlekit.anatomy.voxel_connectivity import goal_connected
    from needlekit.io._binarise import binarise

    points = np.random.default_rng(0).uniform(-40.0, 40.0, size=(64, 3))
    for name in ("lung", "liver", "neck"):  # each at the coarsest grid it accepts
        coarsest = importlib.import_module(f"needlekit.anatomy.phantoms.{name}")
        scene = make_phantom(name, 0, voxel_size_mm=coarsest.VOXEL_SIZE_RANGE_MM[1]).scene
        for s in scene.structures:
            s.field.signed_distance(points)
            s.field.gradient(points)
        field = scene.obstacle_field()
        field.signed_distance(points)
        field.gradient(points)
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=1, radius=10.0)
    ExactMeshDistance(ball).signed_distance(points[:4])
    voxelize_mesh_sdf(ball, voxel_size_mm=4.0)
    Ellipsoid([9.0, 6.0, 4.0]).signed_distance(points)
    for dtype in (np.uint8, np.int16, np.int32, np.int64):
        binarise(np.zeros((4, 5, 6), dtype=dtype, order="F"))
    tube, affine = _vessel_grid()
    obstacles = VoxelObstacles(tube, affine, needle_diameter_mm=1.0)
    nearest_obstacle_distance(obstacles, points, cap_mm=5.0)
    goal_connected(obstacles, np.array([0.0, 0.0, -15.0]), np.array([0.0, 0.0, 15.0]),
                   max_length_mm=100.0, goal_tolerance_mm=1.0, exclusion_mm=3.0,
                   spacing_mm=1.0, subdivide=2, max_cells=1000)  # fmt: skip


def _warm_up_straight_vessel() -> None:
    from needlekit.anatomy.voxel import VoxelSDF

    _warm_up_straight(VoxelSDF.from_mask(*_vessel_grid()))


def _warm_up_mechanics() -> None:
    """The rod's kernels (node positions, reference, offsets, foundation, the banded solve,
    the channel's sampling), with the argument types a physical truth passes: a pre-bent
    needle in an inhomogeneous tissue, turned and inserted; and the closed loop's sensor
    guard and tip filter."""
    from needlekit.mechanics.insertion import MechanicalNeedle
    from needlekit.mechanics.materials import NeedleSpec, TissueSpec

    needle = NeedleSpec(0.5, 0.0, 75e3, 0.5).with_prebend(15.0, 3.0)
    sim = MechanicalNeedle(np.eye(4), needle, TissueSpec(0.1, 0.3), inhomogeneity=0.1,
                           rng=np.random.default_rng(0))  # fmt: skip
    sim.step(0.4, sim.kappa_max_per_mm, 6.0, 1.0)
    sim.step(1.0, 0.0, 2.0, 1.0)
    # the closed loop's own kernels: the sensor guard's screen of a sample and the tip
    # filter's gain (a first `execute` would compile them inside its first trial)
    from needlekit.execute.estimator import _gain
    from needlekit.execute.guard import is_pose

    is_pose(np.eye(4))
    _gain(2.0 * np.eye(6), np.eye(6), np.zeros(6))


def _warm_up_control() -> None:
    """Every kernel of the 1 kHz control step and of the adaptation law, with the argument
    types the puncture study passes: the three steps' QPs (and one with given VFIs), the
    VFIs with their parameter rows, and a keyframe history that merges, keeps a current
    sample and evicts."""
    from needlekit.control.adaptation import (
        AdaptationSettings,
        MeasurementHistory,
        adaptation_step,
    )
    from needlekit.control.controller import (
        ControllerSettings,
        GuideLine,
        Step,
        control_step,
        step_vfis,
    )
    from needlekit.control.dq import dq_to_matrix
    from needlekit.control.panda import PandaModel
    from needlekit.control.parameters import model_from_parameters, parameter_jacobians

    a = np.array([-650.0, 0.0, -450.0, 0.01, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.01, 0.0])
    est = model_from_parameters(PandaModel(), a)
    cs = ControllerSettings()
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    s = est.state(q)
    guide = GuideLine(s.tip_mm - 50.0 * s.needle_axis, -s.needle_axis)
    settings = AdaptationSettings(a - 1.0, a + 1.0)
    history = MeasurementHistory(capacity=2)
    measured = est.tip_pose(q)
    # keyframes (the third evicts one), a merge, then a current sample
    moves = ((Step.APPROACH, 0.0), (Step.PUNCTURE, 0.2), (None, 0.2), (Step.ALIGN, 0.0),
             (Step.APPROACH, 0.01))  # fmt: skip
    for step, dq in moves:
        q = q + dq
        s = est.state(q)
        pj = parameter_jacobians(est, s, a)
        tip = dq_to_matrix(s.tip_dq)
        history.add(
            np.linalg.inv(est.world_T_base) @ tip @ np.linalg.inv(est.flange_T_tip), measured
        )
        vfis, task_error = [], None
        if step is not None:
            vfis = step_vfis(s, step, guide, cs, pj, a)
            out = control_step(est, q, step, guide, cs, desired_mm=s.tip_mm, state=s, vfi_share=0.5)
            control_step(est, q, step, guide, cs, desired_mm=s.tip_mm, vfis=vfis)
            task_error = out.task_error
        adaptation_step(
            a, tip, measured, pj, settings, step=step, task_error=task_error, controller=cs,
            vfis=vfis, vfi_share=0.5, history=history,
        )  # fmt: skip
        adaptation_step(a, tip, measured, pj, settings)  # without a history
    history.stacked(a, 100.0)


def _warm_up_straight(vessel) -> None:
    """Two straight needles through the phantom's elliptic skin past a voxel vessel and a
    superquadric (the ellipse root, the superquadric projection, the trilinear kernels)."""
    from needlekit.anatomy.phantoms._skin import EllipticCylinderSkin
    from needlekit.anatomy.primitives import Superquadric
    from needlekit.anatomy.scene import Role, Scene, Structure
    from needlekit.planning.straight.problem import StraightProblem
    from needlekit.planning.straight.sequence import plan_needles

    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 30.0]
    scene = Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, EllipticCylinderSkin([0, 0], [60, 45], [0, 6.3], [-60, 60])),
            Structure("vessel", Role.OBSTACLE, vessel),
            Structure("duct", Role.OBSTACLE, Superquadric([20.0, 3.0, 3.0], [8.0, 2.0, 2.0], pose)),
        ]
    )  # fmt: skip
    problem = StraightProblem(scene, [0.0, 0.0, 0.0], "skin", up=[0.0, 1.0, 0.0])
    plan_needles(problem, [[0.0, 0.0, 0.0], [0.0, 0.0, 8.0]], resolution_deg=10.0)
    # the approach analysis' segment-mesh kernels, serial and parallel
    import trimesh

    from needlekit.geometry.segment_mesh import PARALLEL_MIN_SEGMENTS, SegmentMeshIntersector

    ball = trimesh.creation.icosphere(subdivisions=1, radius=10.0)
    hits = SegmentMeshIntersector(ball.vertices, ball.faces)
    for n in (4, PARALLEL_MIN_SEGMENTS):
        ends = np.random.default_rng(0).normal(scale=20.0, size=(n, 3))
        hits.any_hit(np.zeros((n, 3)), ends)
        hits.first_hit(np.zeros((n, 3)), ends)


if __name__ == "__main__":  # pragma: no cover - run by make install
    print(f"needlekit: planning and control kernels compiled in {warm_up_kernels():.1f} s")
