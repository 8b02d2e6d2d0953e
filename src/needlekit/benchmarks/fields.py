"""``needlekit bench fields``: distance queries per second and distance-field build times.

Rows: the numba trilinear kernels against the numpy reference on the same seeded points
(the ratio is the figure to compare across machines); building a :class:`VoxelSDF` from a
sphere mask of ``grid_size^3`` voxels (two EDTs); preparing real Med-RAD lung patients as
a first plan gets them when the data is there, each in a fresh process, cold (into an empty
temporary prepared-anatomy cache) and warm (from it), stage by stage with the memory
(:mod:`needlekit.benchmarks.prepare`); baking a mesh into a grid, with the exact mesh
distance's queries per second beside it.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.benchmarks.prepare import (
    COLD_TARGET_S,
    PEAK_TARGET_MB,
    WARM_TARGET_S,
    prepare_in_subprocess,
)
from needlekit.benchmarks.record import best_time, machine_info
from needlekit.errors import InvalidInputError

__all__ = ["run_fields_benchmark"]


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


def _stage_line(record: dict) -> str:
    return ", ".join(f"{k} {v['s']:.2f}" for k, v in record["stages"].items() if v["s"] >= 0.005)


def _medrad_rows(medrad_dir, patients) -> list[dict]:
    """Prepare Med-RAD lung patients for a first plan, each in a fresh process, cold (into
    an empty temporary prepared-anatomy cache) and warm (from it), stage by stage with the
    memory (:mod:`needlekit.benchmarks.prepare`)."""
    from needlekit.io.medrad import medrad_root

    try:
        root = medrad_root(medrad_dir)
    except InvalidInputError as exc:
        return [{"name": "medrad_lung", "skipped": str(exc), "summary": f"skipped: {exc}"}]
    rows = []
    for patient in patients:
        with tempfile.TemporaryDirectory(prefix="needlekit-bench-cache-") as cache:
            cold = prepare_in_subprocess(root, patient, cache)
            entry_mb = sum(p.stat().st_size for p in Path(cache).rglob("*") if p.is_file())
            warm = prepare_in_subprocess(root, patient, cache)
        # the goals are about the preparation: Python's own imports are counted apart
        cold_s = cold["ready_s"] - cold["stages"]["import"]["s"]
        warm_s = warm["ready_s"] - warm["stages"]["import"]["s"]
        warm_plan_s = warm_s + warm["stages"]["first_plan"]["s"]
        peak = max(cold["peak_rss_mb"] or 0.0, warm["peak_rss_mb"] or 0.0)
        verdicts = {
            "cold": cold_s <= COLD_TARGET_S,
            "warm": warm_s <= WARM_TARGET_S,
            "peak_memory": peak <= PEAK_TARGET_MB,
        }
        rows.append(
            {
                "name": f"medrad_lung{patient}",
                "patient": patient,
                "cold_s": cold_s,
                "warm_s": warm_s,
                "warm_with_first_plan_s": warm_plan_s,
                "import_s": {
                    "cold": cold["stages"]["import"]["s"],
                    "warm": warm["stages"]["import"]["s"],
                },
                "peak_rss_mb": peak,
                "targets": {
                    "cold_s": COLD_TARGET_S,
                    "warm_s": WARM_TARGET_S,
                    "peak_rss_mb": PEAK_TARGET_MB,
                },
                "within_targets": verdicts,
                "warm_from_cache": bool(warm["warm"]) and not cold["warm"],
                "cold": cold,
                "warm": warm,
                "cache_entry_mb": entry_mb / 2**20,
                "summary": (
                    f"{cold_s:8.2f} s  Med-RAD lung {patient} ready for a plan cold "
                    f"({_stage_line(cold)}), {warm_s:.2f} s warm ({_stage_line(warm)}); "
                    f"peak {peak:.0f} MiB; targets {COLD_TARGET_S:g} s / {WARM_TARGET_S:g} s / "
                    f"{PEAK_TARGET_MB:g} MiB: "
                    + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in verdicts.items())
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
        with ``build_s``; ``medrad_lungN`` with ``cold_s`` and ``warm_s`` (the patient
        ready for a plan in a fresh process, into an empty temporary prepared-anatomy cache
        and then from it, Python's imports apart), ``peak_rss_mb``, the targets and
        verdicts, and the two runs' ``stages`` (seconds and resident memory each, see
        :mod:`needlekit.benchmarks.prepare`); ``voxelize_mesh``), each with a ``summary``
        line.
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
