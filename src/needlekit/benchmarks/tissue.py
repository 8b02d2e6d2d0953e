"""The deforming organ's cost on a Med-RAD patient: the precomputation cold and warm, and
the loop's step (loads -> displacements of the corridor and tracked points).

The organ body is the organ's mask with the nodule and the vessels and airways lying in it
(:func:`~needlekit.tissue.meshing.organ_body`), meshed at the default setting keeping the
component of the target (one lung). The corridor is the straight line from the patient's
first start to its target, a point every ``spacing_mm``; the tracked points are the target and up to ``per_structure``
voxels of every vessel and airway structure within ``radius_mm`` of the corridor. A step
is :meth:`needlekit.tissue.runtime.DeformingTissue.apply` with ``n_loads`` loads spread
along the inserted part of the corridor as it is now (0.5 mm beside it, forces of about 0.1 N, as an
elastic needle's ``shaft_loads()`` gives) and a breathing displacement, timed one by one.

Run: ``python -m needlekit.benchmarks.tissue --organ lung --patient 1`` (the Med-RAD
folder from ``$NEEDLEKIT_MEDRAD``); it prints one JSON record.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time

import numpy as np

from needlekit.benchmarks.timing import step_statistics
from needlekit.execute.breathing import PRESETS
from needlekit.io.finite_json import json_text
from needlekit.io.medrad_paths import patient_folder
from needlekit.io.poses import read_point_txt, read_pose_txt
from needlekit.tissue.compliance import locate, precompute, resample_polyline
from needlekit.tissue.fem import BOUNDARY_MODES, SOLVERS
from needlekit.tissue.medrad_organ import ORGAN_FILES, organ_inputs
from needlekit.tissue.meshing import DEFAULT_TARGET_TETS, dihedral_angles_deg
from needlekit.tissue.runtime import DeformingTissue

__all__ = ["run_tissue_benchmark", "step_times"]


def step_times(
    tissue: DeformingTissue, n_steps: int = 4000, n_loads: int = 40, seed: int = 0
) -> dict:
    """Time ``n_steps`` calls of :meth:`DeformingTissue.apply`, each with ``n_loads`` loads
    beside the corridor and a breathing displacement.

    Parameters
    ----------
    tissue : DeformingTissue
    n_steps, n_loads, seed : int

    Returns
    -------
    dict
        ``wall`` and ``cpu`` (the thread's own CPU time, which a process preempted by
        others on a shared machine does not count):
        :func:`~needlekit.benchmarks.timing.step_statistics` (microseconds).
    """
    rng = np.random.default_rng(seed)
    corridor = tissue.compliance.corridor_mm
    axis = corridor[-1] - corridor[0]
    side = np.cross(
        axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 * np.linalg.norm(axis) else [0, 1, 0]
    )
    side *= 0.5 / np.linalg.norm(side)
    trace = PRESETS["lung"].trace(rng, 60.0)
    times, cpu = np.empty(n_steps), np.empty(n_steps)
    for k in range(n_steps):
        depth = 1 + (k % (len(corridor) - 1))  # the needle advancing along the corridor
        idx = np.linspace(0, depth, n_loads)
        now = tissue.positions_mm("corridor")  # the needle goes where the tissue is now
        pts = np.stack([np.interp(idx, np.arange(len(now)), now[:, c]) for c in range(3)], 1)
        forces = rng.normal(0.0, 0.1 / np.sqrt(3), (n_loads, 3))
        d = trace.actual(k * 0.025)
        c0, t0 = time.thread_time(), time.perf_counter()
        tissue.apply(pts + side, forces, breathing=d)
        tissue.target_mm()
        times[k], cpu[k] = time.perf_counter() - t0, time.thread_time() - c0
    return {"wall": step_statistics(times), "cpu": step_statistics(cpu)}


def run_tissue_benchmark(
    organ: str = "lung",
    patient: int = 1,
    root=None,
    *,
    spacing_mm: float = 1.5,
    radius_mm: float = 15.0,
    per_structure: int = 100,
    target_tets: int = DEFAULT_TARGET_TETS,
    n_steps: int = 4000,
    n_loads: int = 40,
    solver: str = "auto",
    boundary_mode: str = "organ",
) -> dict:
    """Mesh, precompute (cold, then warm from the cache) and time the step on one patient.

    Parameters
    ----------
    organ : str
    patient : int
    root : path-like, optional
        The Med-RAD folder.
    spacing_mm, radius_mm : float
    per_structure, target_tets, n_steps, n_loads : int
    solver : str
        :class:`~needlekit.tissue.fem.ElasticProblem`'s.
    boundary_mode : str
        :func:`~needlekit.tissue.fem.organ_boundary`'s.

    Returns
    -------
    dict
    """
    folder = patient_folder(organ, patient, root)
    t0 = time.perf_counter()
    target = read_point_txt(folder / "target.txt")
    start = read_pose_txt(folder / "start1.txt")[:3, 3]
    corridor = resample_polyline([start, target], spacing_mm)
    body, mask_affine, tracked, labels = organ_inputs(folder, organ, corridor, target,
                                                      radius_mm, per_structure)  # fmt: skip
    read_s = time.perf_counter() - t0
    settings = {"target_tets": target_tets, "seed_mm": target, "solver": solver,  # the target's lung
                "boundary_mode": boundary_mode}  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="needlekit-tissue-bench-") as cache:
        t0 = time.perf_counter()
        cold = precompute(
            body, mask_affine, organ, corridor, tracked, labels, cache_dir=cache, **settings
        )
        cold_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        warm = precompute(
            body, mask_affine, organ, corridor, tracked, labels, cache_dir=cache, **settings
        )
        warm_s = time.perf_counter() - t0
    mesh = cold.mesh
    _, _, in_mesh = locate(mesh, np.concatenate([corridor, target[None]]))
    tissue = DeformingTissue(warm)
    steps = step_times(tissue, n_steps, n_loads)
    # the size of the effect: the target's displacement under 0.5 N along the corridor at
    # the target, and under the organ's breathing preset at its peak
    f_axis = (target - start) / np.linalg.norm(target - start)
    tissue.apply(corridor[-3:], np.tile(0.5 / 3 * f_axis, (3, 1)))
    push = float(np.linalg.norm(tissue.target_displacement_mm))
    b = PRESETS[organ]
    tissue.apply(
        np.zeros((0, 3)), np.zeros((0, 3)), breathing=b.amplitude_mm * np.asarray(b.direction)
    )
    breath = float(np.linalg.norm(tissue.target_displacement_mm))
    return {
        "organ": organ, "patient": patient, "read_mask_s": read_s,
        "tets": mesh.n_tets, "nodes": mesh.n_nodes, "cell_mm": mesh.cell_mm.tolist(),
        "min_dihedral_deg": float(dihedral_angles_deg(mesh.nodes_mm, mesh.tets).min()),
        "corridor_points": len(corridor), "tracked_points": len(tracked),
        "corridor_points_in_mesh": int(in_mesh[:-1].sum()), "target_in_mesh": bool(in_mesh[-1]),
        "precompute_cold_s": cold_s, "cold_timings_s": cold.info["timings_s"],
        "precompute_warm_s": warm_s, "warm_timings_s": warm.info["timings_s"],
        "solver": cold.info["solver"], "boundary": boundary_mode, "step_us": steps, "n_loads": n_loads,
        "target_push_0.5N_mm": push, "target_breathing_peak_mm": breath,
        "breathing_amplitude_mm": b.amplitude_mm,
    }  # fmt: skip


def main(argv=None) -> int:
    """``python -m needlekit.benchmarks.tissue``: one JSON record on stdout."""
    p = argparse.ArgumentParser(
        prog="python -m needlekit.benchmarks.tissue", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--organ", choices=sorted(ORGAN_FILES), default="lung")
    p.add_argument("--patient", type=int, default=1)
    p.add_argument("--medrad", default=None, help="the Med-RAD folder (default $NEEDLEKIT_MEDRAD)")
    p.add_argument("--steps", type=int, default=4000)
    p.add_argument("--target-tets", type=int, default=DEFAULT_TARGET_TETS)
    p.add_argument("--solver", choices=SOLVERS, default="auto")
    p.add_argument("--boundary", choices=BOUNDARY_MODES, default="organ")
    a = p.parse_args(argv)
    out = run_tissue_benchmark(a.organ, a.patient, a.medrad, n_steps=a.steps,
                               target_tets=a.target_tets, solver=a.solver,
                               boundary_mode=a.boundary)  # fmt: skip
    sys.stdout.write(json_text(out, "tissue benchmark", indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
