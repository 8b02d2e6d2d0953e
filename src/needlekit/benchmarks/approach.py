"""``needlekit bench approach``: the approach analysis beside 3D Slicer's
PercutaneousApproachAnalysis (PAA), on the same meshes, in the same process.

PAA (the Slicer extension) loops in Python over the skin model's triangles and asks a VTK
``vtkModifiedBSPTree`` of the obstacle models whether the line from each triangle's centre
to the target meets them (``IntersectWithLine``, tolerance 0.001); its label-wise mode does
that for every voxel of a target label. The reference here is that procedure, run with
VTK's own BSP tree (installed with ``pip install 'needlekit[paa]'``; without it the
reference is recorded as skipped, saying why). needlekit's side, timed the same way: the
same work (the obstacles' search structure built, one exact line test per skin triangle);
apart, the whole :func:`~needlekit.planning.straight.approach.approach_analysis` (lines,
inside the body, angles), and the same with needlekit's criteria (needle radius, gamma).

Case: Med-RAD liver 4 through ``examples/medrad_liver4.yaml`` (its liver capsule meshed by
marching cubes as the skin, its hepatic artery, hepatic vein and portal vein as the
obstacle models, the case's target), when the data is there. Recorded: the mesh sizes,
each side's time (median of ``repeat``), the ratio, and how many triangles the two
answers differ on (with the ones that differ: how far their lines pass from the obstacle
surface, by the exact mesh distance sampled along them). Meshing is excluded and reported
apart. Speed is measured, never asserted.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.benchmarks.straight import _examples_dir, _medrad_env, _timed
from needlekit.errors import NeedlekitError
from needlekit.planning.straight.approach import (
    _obstacle_intersector,
    approach_analysis,
    approach_scores,
    structure_mesh,
)
from needlekit.provenance import machine_info
from needlekit.scenario.straight import multi_problem_from_scenario

__all__ = ["run_approach_benchmark"]

#: PAA's IntersectWithLine tolerance.
PAA_TOLERANCE: float = 0.001
#: Target voxels of the label-wise comparison (PAA's loop is slow: a sample of them).
LABEL_VOXELS: int = 16


def _vtk_polydata(meshes):
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    verts, faces, base = [], [], 0
    for m in meshes:
        verts.append(np.asarray(m.vertices, dtype=float))
        faces.append(np.asarray(m.faces, dtype=np.int64) + base)
        base += len(m.vertices)
    v = np.concatenate(verts)
    f = np.concatenate(faces)
    points = vtk.vtkPoints()
    points.SetData(numpy_to_vtk(v, deep=True))
    # VTK 9's layout: each triangle's start in the connectivity, then the vertex ids
    # (SetCells' legacy count-prefixed layout is deprecated from VTK 9.6)
    offsets = np.arange(0, 3 * len(f) + 1, 3, dtype=np.int64)
    polys = vtk.vtkCellArray()
    polys.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(np.ascontiguousarray(f.ravel()), deep=True))  # fmt: skip
    poly = vtk.vtkPolyData()
    poly.SetPoints(points)
    poly.SetPolys(polys)
    return poly


def _paa_lines(centres: np.ndarray, target: np.ndarray, obstacles) -> np.ndarray:
    """PAA's procedure: a BSP tree of the obstacles, one IntersectWithLine per triangle."""
    import vtk

    tree = vtk.vtkModifiedBSPTree()
    tree.SetDataSet(_vtk_polydata(obstacles))
    tree.BuildLocator()
    t = vtk.reference(0.0)
    x = [0.0, 0.0, 0.0]
    pcoords = [0.0, 0.0, 0.0]
    sub = vtk.reference(0)
    p_target = [float(c) for c in target]
    hit = np.zeros(len(centres), dtype=bool)
    for i, c in enumerate(centres):
        hit[i] = tree.IntersectWithLine(list(c), p_target, PAA_TOLERANCE, t, x, pcoords, sub) > 0
    return hit


def _reference_available() -> str | None:
    try:
        import vtk  # noqa: F401
    except ImportError:
        return "vtk not installed (pip install 'needlekit[paa]')"
    return None


def _case(name: str, path: Path, repeat: int) -> dict:
    from needlekit.anatomy.scene import Role
    from needlekit.scenario.loading import load_scenario

    sc = load_scenario(path)
    multi, _ = multi_problem_from_scenario(sc)
    pr = multi.problem
    target = np.asarray(sc.goal.point_mm if sc.goal is not None else multi.targets_mm[0], float)
    t0 = time.perf_counter()
    skin = structure_mesh(pr.scene[pr.entry_surface])
    obstacles = [structure_mesh(s) for s in pr.scene.by_role(Role.OBSTACLE)]
    mesh_s = time.perf_counter() - t0

    lines = approach_analysis(target, skin, obstacles)  # untimed: numba kernels load
    centres = lines.centres_mm
    ends = np.broadcast_to(target, centres.shape)
    # PAA's work: a search structure over the obstacles, then one line per skin triangle
    lines_t, hit = _timed(lambda: _obstacle_intersector(obstacles).any_hit(centres, ends), repeat)
    analysis_t, _ = _timed(lambda: approach_analysis(target, skin, obstacles), repeat)
    full_t, full = _timed(
        lambda: approach_analysis(
            target,
            skin,
            obstacles,
            field=pr.obstacle_field(),
            needle_radius_mm=pr.needle.radius_mm,
            gamma_mm=pr.gamma_mm,
            max_length_mm=pr.needle.max_length_mm,
            max_normal_angle_deg=pr.max_normal_angle_deg,
        ),
        repeat,
    )
    case: dict[str, Any] = {
        "name": name,
        "scenario": str(path),
        "target_mm": target.tolist(),
        "skin_faces": int(len(skin.faces)),
        "obstacle_faces": int(sum(len(m.faces) for m in obstacles)),
        "meshes_s": mesh_s,
        "needlekit_lines": {
            **lines_t,
            "score": lines.score_paa,
            "same_as_analysis": bool(np.array_equal(hit, lines.hit)),
        },
        "needlekit_analysis": analysis_t,
        "needlekit_full": {
            **full_t,
            "score": full.score,
            "gamma_mm": pr.gamma_mm,
            "needle_radius_mm": pr.needle.radius_mm,
        },
    }
    # the label-wise mode on a sample of the target's voxels
    rng = np.random.default_rng(0)
    nodule = next(s for s in pr.scene.structures if s.role is Role.TARGET)
    lo, hi = nodule.field.bounds()
    cand = rng.uniform(lo, hi, size=(4000, 3))
    voxels = cand[nodule.field.signed_distance(cand) < 0][:LABEL_VOXELS]
    label_t, label_scores = _timed(lambda: approach_scores(voxels, skin, obstacles), 1)
    case["label_wise"] = {"voxels": int(len(voxels)), "needlekit": label_t}
    why = _reference_available()
    if why is not None:
        case["reference"] = {"skipped": why}
        return case
    import vtk

    paa_t, paa_hit = _timed(lambda: _paa_lines(centres, target, obstacles), repeat)
    differ = np.flatnonzero(paa_hit != lines.hit)
    near = []
    if differ.size:
        # how far each line the two answers differ on passes from the obstacles' surface:
        # the exact mesh distance at 4001 points along it (the smallest, and its sign)
        import trimesh

        from needlekit.anatomy.mesh import ExactMeshDistance

        surface = ExactMeshDistance(trimesh.util.concatenate(obstacles))
        t = np.linspace(0.0, 1.0, 4001)[:, None]
        for i in differ:
            d = surface.signed_distance(centres[i] + t * (target - centres[i]))
            near.append(
                {
                    "face": int(i),
                    "paa_hit": bool(paa_hit[i]),
                    "needlekit_hit": bool(lines.hit[i]),
                    "closest_sampled_mm": float(d[np.argmin(np.abs(d))]),
                }
            )

    def paa_label():
        out = []
        for p in voxels:
            h = _paa_lines(centres, p, obstacles)
            out.append(float(lines.areas_mm2[~h].sum() / lines.areas_mm2.sum()))
        return np.array(out)

    paa_label_t, paa_scores = _timed(paa_label, 1)
    case["reference"] = {
        "what": "PAA's procedure: vtkModifiedBSPTree.IntersectWithLine per skin triangle",
        "vtk": vtk.vtkVersion.GetVTKVersion(),
        "lines": {**paa_t, "score": float(lines.areas_mm2[~paa_hit].sum() / lines.areas_mm2.sum())},
        "ratio_paa_over_needlekit": paa_t["median_s"] / lines_t["median_s"],
        "triangles_differing": int(differ.size),
        "differing": near,
        "label_wise": {
            **paa_label_t,
            "ratio_paa_over_needlekit": paa_label_t["median_s"] / label_t["median_s"],
            "max_score_difference": float(np.max(np.abs(paa_scores - label_scores))),
        },
    }
    return case


def _results(cases: list[dict]) -> list[dict]:
    """One printable row per case and stage."""
    rows = []
    for c in cases:
        if "skipped" in c:
            rows.append({"name": c["name"], "summary": f"skipped: {c['skipped']}"})
            continue
        ref = c["reference"]
        lines = c["needlekit_lines"]
        text = (
            f"{c['skin_faces']} skin / {c['obstacle_faces']} obstacle triangles; needlekit "
            f"{lines['median_s']:.4f} s (score {lines['score']:.4f})"
        )
        if "skipped" in ref:
            text += f"; PAA reference skipped: {ref['skipped']}"
        else:
            text += (
                f", PAA {ref['lines']['median_s']:.3f} s (score {ref['lines']['score']:.4f}): "
                f"{ref['ratio_paa_over_needlekit']:.0f}x; {ref['triangles_differing']} "
                "triangles differ"
            )
        rows.append({"name": f"{c['name']} lines", "summary": text})
        full = c["needlekit_full"]
        rows.append(
            {
                "name": f"{c['name']} needlekit",
                "summary": f"whole analysis {c['needlekit_analysis']['median_s']:.4f} s (lines, "
                f"inside the body, angles); {full['median_s']:.4f} s with radius "
                f"{full['needle_radius_mm']:g} mm, gamma {full['gamma_mm']:g} mm (score "
                f"{full['score']:.4f}); meshes {c['meshes_s']:.2f} s (excluded)",
            }
        )
        lw = c["label_wise"]
        text = f"{lw['voxels']} voxels: needlekit {lw['needlekit']['median_s']:.3f} s"
        if "label_wise" in ref:
            r = ref["label_wise"]
            text += (
                f", PAA {r['median_s']:.2f} s: {r['ratio_paa_over_needlekit']:.0f}x; largest "
                f"score difference {r['max_score_difference']:.2e}"
            )
        rows.append({"name": f"{c['name']} label-wise", "summary": text})
    return rows


def run_approach_benchmark(*, repeat: int = 3, medrad_dir=None) -> dict:
    """Run the benchmark (module notes).

    Parameters
    ----------
    repeat : int
        Timed runs per side (median, min).
    medrad_dir : path-like, optional
        Med-RAD folder (default ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``).

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs`` and ``cases``.
    """
    examples = _examples_dir()
    path = examples / "medrad_liver4.yaml"

    load_before = list(os.getloadavg())
    cases = []
    with _medrad_env(medrad_dir):
        from needlekit.io.medrad import list_patients, medrad_root

        try:
            root = medrad_root(medrad_dir)
            have = 4 in list_patients("liver", root)
        except NeedlekitError as exc:  # no Med-RAD folder: recorded as the reason
            have, root = False, str(exc)
        if not path.is_file():
            cases.append({"name": "medrad_liver4", "skipped": f"{path} not found"})
        elif not have:
            cases.append({"name": "medrad_liver4", "skipped": f"no Med-RAD liver 4 ({root})"})
        else:
            cases.append(_case("medrad_liver4", path, repeat))
    return {
        "benchmark": "approach",
        "results": _results(cases),
        "machine": machine_info(),
        "load_average": {"before": load_before, "after": list(os.getloadavg())},
        "inputs": {"repeat": repeat, "medrad_dir": None if medrad_dir is None else str(medrad_dir),
                   "paa_tolerance": PAA_TOLERANCE, "label_voxels": LABEL_VOXELS},
        "cases": cases,
    }  # fmt: skip
