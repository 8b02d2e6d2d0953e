"""``needlekit bench fields``: distance queries per second and distance-field build times.

Rows: the numba trilinear kernels against the numpy reference on the same seeded points
(the ratio is the figure to compare across machines); building a :class:`VoxelSDF` from a
sphere mask of ``grid_size^3`` voxels (two EDTs); preparing real Med-RAD lung patients as
a first plan gets them (masks read, combined obstacle field, the obstacles' own fields and
the obstacle voxels) when the data is there, cold (into an empty temporary
prepared-anatomy cache) and warm (from it); baking a mesh into a grid, with the exact mesh
distance's queries per second beside it.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.benchmarks.record import best_time, machine_info

__all__ = ["run_fields_benchmark"]

_LUNG_MASK = Path("Lungs") / "TumorTargetEnvironments" / "Patient1" / "pleuralBoundary.nii.gz"


def _query_rows(grid_size: int, n_queries: int, repeat: int, seed: int) -> list[dict]:
    from needlekit.anatomy.voxel import (
        _trilinear,
        _trilinear_gradient,
        trilinear_reference,
    )

    rng = np.random.default_rng(seed)
    values = rng.normal(size=(grid_size,) * 3).astype(np.float32)
    affine = np.diag([0.7, 0.7, 0.7, 1.0])
    inv = np.linalg.inv(affine)
    points = rng.uniform(0.0, 0.7 * (grid_size - 1), (n_queries, 3))
    ref_n = min(n_queries, 200_000)
    out = np.empty(n_queries)
    grad = np.empty((n_queries, 3))
    rows = []
    for name, fast, want_grad in (
        ("trilinear", lambda n: _trilinear(values, inv, points[:n], out[:n]), False),
        (
            "trilinear_gradient",
            lambda n: _trilinear_gradient(values, inv, points[:n], out[:n], grad[:n]),
            True,
        ),
    ):
        t0 = time.perf_counter()
        fast(10)
        first_call = time.perf_counter() - t0
        fast(ref_n)
        ref = trilinear_reference(values, inv, points[:ref_n], gradient=want_grad)
        got = (out[:ref_n], grad[:ref_n]) if want_grad else out[:ref_n]
        diff = (
            max(float(np.abs(a - b).max()) for a, b in zip(got, ref, strict=True))
            if want_grad
            else float(np.abs(got - ref).max())
        )
        t_fast = best_time(lambda f=fast: f(n_queries), repeat)
        t_ref = best_time(
            lambda g=want_grad: trilinear_reference(values, inv, points[:ref_n], gradient=g),
            max(1, repeat // 2),
        )
        rate, ref_rate = n_queries / t_fast, ref_n / t_ref
        rows.append(
            {
                "name": name,
                "queries_per_s": rate,
                "reference_queries_per_s": ref_rate,
                "speedup_vs_reference": rate / ref_rate,
                "first_call_s": first_call,
                "max_abs_diff_mm": diff,
                "summary": (
                    f"{rate / 1e6:8.2f} M queries/s on a {grid_size}^3 grid  (numpy "
                    f"reference {ref_rate / 1e6:.2f} M/s, x{rate / ref_rate:.0f}; first call "
                    f"{first_call:.2f} s)"
                ),
            }
        )
    return rows


def _edt_row(grid_size: int, repeat: int) -> dict:
    from needlekit.anatomy.voxel import VoxelSDF

    n = grid_size
    axis = np.arange(n, dtype=np.float32) - n / 2
    r2 = axis[:, None, None] ** 2 + axis[None, :, None] ** 2 + axis[None, None, :] ** 2
    mask = r2 <= (0.4 * n) ** 2
    del r2
    affine = np.diag([0.7, 0.7, 0.7, 1.0])
    t = best_time(lambda: VoxelSDF.from_mask(mask, affine, crop=False), repeat)
    sdf = VoxelSDF.from_mask(mask, affine, crop=False)
    mb = sdf.values.nbytes / 2**20
    return {
        "name": f"from_mask_{n}^3",
        "build_s": t,
        "voxels": int(mask.size),
        "grid_shape": list(sdf.shape),
        "values_mb": mb,
        "error_bound_mm": sdf.error_bound_mm,
        "summary": (
            f"{t:8.2f} s  signed EDT of a {n}^3 sphere mask ({mask.size / t / 1e6:.0f} M "
            f"voxels/s, {mb:.0f} MB float32, bound {sdf.error_bound_mm:.3f} mm)"
        ),
    }


#: The issue's target for building a lung patient's planning fields (s, 2 cores).
MEDRAD_LUNG_TARGET_S: float = 15.0


def _prepare_for_a_plan(root, patient: int, cache_dir) -> tuple[Any, float, dict]:
    """Load a lung as ``needlekit plan`` does: the case (free-space field), the obstacles'
    own fields (the start's entry surface is looked up among them) and the obstacle voxels
    for a 1 mm needle. Returns the case, the total time and the stages."""
    from needlekit.anatomy.scene import Role
    from needlekit.io.medrad import load_medrad

    t0 = time.perf_counter()
    case = load_medrad("lung", patient, root, cache_dir=cache_dir)
    t_case = time.perf_counter() - t0
    t1 = time.perf_counter()
    for s in case.scene.by_role(Role.OBSTACLE):
        s.field.get()
    t_fields = time.perf_counter() - t1
    t1 = time.perf_counter()
    case.voxel_obstacles(1.0)
    t_voxels = time.perf_counter() - t1
    total = time.perf_counter() - t0
    stages = {
        **case.timings_s,
        "load_medrad_s": t_case,
        "structure_fields_s": t_fields,
        "voxel_obstacles_s": t_voxels,
    }
    return case, total, stages


def _medrad_rows(medrad_dir, patients) -> list[dict]:
    """Prepare Med-RAD lung patients as a first plan gets them, cold (into an empty
    temporary prepared-anatomy cache) and warm (from it)."""
    from needlekit.errors import InvalidInputError
    from needlekit.io.medrad import medrad_root

    try:
        root = medrad_root(medrad_dir)
    except InvalidInputError as exc:
        return [{"name": "medrad_lung", "skipped": str(exc), "summary": f"skipped: {exc}"}]
    rows = []
    for patient in patients:
        with tempfile.TemporaryDirectory(prefix="needlekit-bench-cache-") as cache:
            case, cold, stages_cold = _prepare_for_a_plan(root, patient, cache)
            field = case.scene.obstacle_field()
            grid = field.base.shape if hasattr(field.base, "shape") else None
            bound = field.error_bound_mm
            entry_mb = sum(p.stat().st_size for p in Path(cache).rglob("*") if p.is_file())
            del case, field
            case, warm, stages_warm = _prepare_for_a_plan(root, patient, cache)
            hit = case.cache_entry is not None and "cache_load_s" in case.timings_s
            del case
        load_s = stages_cold.get("load_s", float("nan"))
        field_s = stages_cold.get("obstacle_field_s", float("nan"))
        first = stages_cold["load_medrad_s"]
        rows.append(
            {
                "name": f"medrad_lung{patient}",
                "patient": patient,
                "load_s": load_s,
                "obstacle_field_s": field_s,
                "total_s": first,
                "target_s": MEDRAD_LUNG_TARGET_S,
                "within_target": first <= MEDRAD_LUNG_TARGET_S,
                "cold_s": cold,
                "warm_s": warm,
                "warm_from_cache": hit,
                "stages_cold": stages_cold,
                "stages_warm": stages_warm,
                "cache_entry_mb": entry_mb / 2**20,
                "grid_shape": None if grid is None else list(grid),
                "error_bound_mm": bound,
                "summary": (
                    f"{cold:8.2f} s  Med-RAD lung {patient} prepared for a plan, cold: read "
                    f"masks {load_s:.2f} s + free-space field {field_s:.2f} s + storing "
                    f"{stages_cold.get('cache_write_s', float('nan')):.2f} s + obstacle fields "
                    f"{stages_cold['structure_fields_s']:.2f} s; warm {warm:.2f} s from the "
                    f"cache ({entry_mb / 2**20:.0f} MB; load alone {first:.2f} s, target <= "
                    f"{MEDRAD_LUNG_TARGET_S:g} s; bound {bound:.3f} mm)"
                ),
            }
        )
    return rows


def _mesh_row(voxel_size_mm: float, seed: int) -> dict:
    import trimesh

    from needlekit.anatomy.mesh import ExactMeshDistance, voxelize_mesh_sdf

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=30.0)
    t0 = time.perf_counter()
    sdf = voxelize_mesh_sdf(mesh, voxel_size_mm)
    t_build = time.perf_counter() - t0
    exact = ExactMeshDistance(mesh)
    pts = np.random.default_rng(seed).uniform(-35.0, 35.0, (5000, 3))
    t0 = time.perf_counter()
    d = exact.signed_distance(pts)
    exact_rate = len(pts) / (time.perf_counter() - t0)
    err = float(np.abs(sdf.signed_distance(pts) - d).max())
    return {
        "name": "voxelize_mesh",
        "faces": len(mesh.faces),
        "voxel_size_mm": voxel_size_mm,
        "grid_shape": list(sdf.shape),
        "build_s": t_build,
        "exact_queries_per_s": exact_rate,
        "max_abs_error_mm": err,
        "error_bound_mm": sdf.error_bound_mm,
        "summary": (
            f"{t_build:8.2f} s  {len(mesh.faces)}-face sphere -> grid {sdf.shape} at "
            f"{voxel_size_mm} mm (max error {err:.3f} <= bound {sdf.error_bound_mm:.3f} mm; "
            f"exact mesh distance {exact_rate / 1e3:.0f} k queries/s)"
        ),
    }


def run_fields_benchmark(
    grid_size: int = 256,
    n_queries: int = 2_000_000,
    repeat: int = 3,
    seed: int = 0,
    medrad_dir: str | os.PathLike | None = None,
    mesh_voxel_size_mm: float = 0.5,
    medrad_patients: tuple[int, ...] = (1,),
) -> dict[str, Any]:
    """Time distance queries and distance-field construction.

    Parameters
    ----------
    grid_size : int
        Edge (voxels) of the cubic grids queried and built.
    n_queries : int
        Random in-grid points per timed batch of queries.
    repeat : int
        Timed repetitions; the best is reported.
    seed : int
        Seed of the random grid values and points.
    medrad_dir : path-like, optional
        Med-RAD folder (default: :func:`needlekit.io.medrad.medrad_root`); the Med-RAD
        rows are marked skipped when the data is absent.
    mesh_voxel_size_mm : float
        Voxel size of the mesh voxelisation row.
    medrad_patients : tuple of int
        Lung patients to load (reading the masks and building the combined obstacle
        field, as planners get them).

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs`` and ``results`` (rows ``trilinear``,
        ``trilinear_gradient`` with ``queries_per_s`` and the reference's; ``from_mask_N^3``
        with ``build_s``; ``medrad_lungN`` with ``load_s``, ``obstacle_field_s``,
        ``total_s`` (the cold load) against ``target_s``, and ``cold_s``/``warm_s`` with
        ``stages_cold``/``stages_warm``: preparing the patient for a plan into an empty
        temporary prepared-anatomy cache, then from it; ``voxelize_mesh``), each with a
        ``summary`` line.
    """
    results = _query_rows(grid_size, n_queries, repeat, seed)
    results.append(_edt_row(grid_size, repeat))
    results.extend(_medrad_rows(medrad_dir, medrad_patients))
    results.append(_mesh_row(mesh_voxel_size_mm, seed))
    return {
        "benchmark": "fields",
        "machine": machine_info(),
        "inputs": {
            "grid_size": grid_size,
            "n_queries": n_queries,
            "repeat": repeat,
            "seed": seed,
            "medrad_dir": None if medrad_dir is None else str(medrad_dir),
            "medrad_patients": list(medrad_patients),
            "mesh_voxel_size_mm": mesh_voxel_size_mm,
        },
        "results": results,
    }
