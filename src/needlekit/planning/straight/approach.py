"""Approach analysis on a skin mesh: what 3D Slicer's PercutaneousApproachAnalysis computes,
exactly, and what it cannot (``needlekit approach``; ``needlekit bench approach`` runs
PAA's own procedure beside it).

PercutaneousApproachAnalysis (PAA; Slicer extension of the SNR lab) answers, for a target
point and a skin model, which skin triangles a straight needle can come from: for each
triangle, the line from its centre to the target is tested against the obstacle models
(a VTK BSP tree); the **approach score** is the accessible skin area over the whole skin
area, and the shortest accessible line is reported with its skin point. Its label-wise
mode repeats this for every voxel of a target label map. It models no needle thickness,
no safety margin, no angle limits, and counts lines that leave and re-enter the body.

:func:`approach_analysis` computes the same per-triangle answer exactly (each line against
every obstacle triangle, :class:`~needlekit.geometry.segment_mesh.SegmentMeshIntersector`:
Moller-Trumbore in float64 over a uniform grid, no tolerance), the same score and shortest
line, and beside them needlekit's own criteria, each optional. Exactly, to rounding: PAA's
BSP tree counts a line within its tolerance (0.001) of an obstacle as a hit, this does
not; and a line through an obstacle's edge or vertex within rounding can be missed by both
neighbouring triangles (Moller-Trumbore is not watertight), which for a closed obstacle
takes two such grazes, one where the line enters and one where it leaves.

- **the needle's thickness and a safety distance**: the certified clearance of the
  needle's surface (radius ``r``) to the obstacles' distance field, at least gamma
  (:func:`~needlekit.planning.straight.cfrw.clearance_bound`: a lower bound, the field's
  error bound subtracted);
- **inside the body**: the line from the target meets the skin first at its own triangle
  (it does not leave the body and come back);
- **the needle's length** and **the angle to the skin's inward normal**.

``accessible_paa`` is PAA's answer (no obstacle triangle on the line); ``accessible`` is
needlekit's (all of the above). :func:`approach_scores` is the label-wise mode: the score
of every target voxel. ``needlekit approach`` runs both on a scenario (its entry surface
as the skin, its obstacles as the obstacle models).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from needlekit._validation import as_points
from needlekit.anatomy.fields import LazyField
from needlekit.errors import InvalidInputError
from needlekit.records import field_of

__all__ = [
    "ApproachAnalysis",
    "approach_analysis",
    "approach_meshes",
    "approach_scores",
    "reach_box",
    "structure_mesh",
]

#: Fraction of a line's length, near its skin end, left out when asking whether the line
#: meets the skin before its own triangle (the own triangle is met at the end).
_OWN_FACE_SLACK: float = 1e-9


@dataclass(frozen=True)
class ApproachAnalysis:
    """The approach analysis of one target on a skin mesh (per skin triangle).

    Attributes
    ----------
    target_mm : ndarray, shape (3,)
    centres_mm : ndarray, shape (n, 3)
        Skin triangle centres (the entry points).
    areas_mm2 : ndarray, shape (n,)
    length_mm : ndarray, shape (n,)
        Centre to target.
    hit : ndarray of bool, shape (n,)
        The line meets an obstacle triangle (PAA's test, exact).
    leaves_body : ndarray of bool, shape (n,)
        The line from the target meets the skin before its own triangle.
    normal_angle_deg : ndarray, shape (n,)
        Angle between the insertion direction and the triangle's inward normal.
    clearance_mm : ndarray, shape (n,) or None
        Certified clearance of the needle's surface (None without a distance field).
    accessible_paa : ndarray of bool, shape (n,)
        PAA's answer: no obstacle on the line.
    accessible : ndarray of bool, shape (n,)
        needlekit's: no obstacle, clearance >= gamma, inside the body, length and angle
        within their limits.
    settings : dict
        ``needle_radius_mm``, ``gamma_mm``, ``max_length_mm``, ``max_normal_angle_deg``.
    certified_shortest : dict or None
        needlekit's chosen line (:meth:`shortest`): the shortest accessible one whose
        needle, its points rounded as the record holds them, passes the straight clearance
        rule (:func:`~needlekit.planning.straight.certify.certify_segment`), with its
        certified clearance; None when none does (or without a field, when a thickness or
        gamma cannot be checked).
    """

    target_mm: np.ndarray
    centres_mm: np.ndarray
    areas_mm2: np.ndarray
    length_mm: np.ndarray
    hit: np.ndarray
    leaves_body: np.ndarray
    normal_angle_deg: np.ndarray
    clearance_mm: np.ndarray | None
    accessible_paa: np.ndarray
    accessible: np.ndarray
    settings: dict
    certified_shortest: dict | None = None

    @staticmethod
    def _score(areas, ok) -> float:
        total = float(areas.sum())
        return float(areas[ok].sum()) / total if total > 0 else 0.0

    @property
    def score_paa(self) -> float:
        """PAA's approach score: accessible skin area over all skin area."""
        return self._score(self.areas_mm2, self.accessible_paa)

    @property
    def score(self) -> float:
        """The same with needlekit's criteria."""
        return self._score(self.areas_mm2, self.accessible)

    def shortest(self, paa: bool = False) -> dict | None:
        """The shortest accessible line: ``{"face", "length_mm", "entry_mm"}`` or None.

        Parameters
        ----------
        paa : bool
            By PAA's criterion (no certificate: PAA's own answer) instead of needlekit's
            (:attr:`certified_shortest`, which adds ``clearance_mm``).

        Returns
        -------
        dict or None
        """
        if not paa:  # needlekit's: certified as recorded (approach_analysis)
            return None if self.certified_shortest is None else dict(self.certified_shortest)
        ok = self.accessible_paa
        if not ok.any():
            return None
        idx = np.flatnonzero(ok)
        i = int(idx[np.argmin(self.length_mm[idx])])
        return {
            "face": i,
            "length_mm": float(self.length_mm[i]),
            "entry_mm": self.centres_mm[i].tolist(),
        }

    def to_dict(self, *, per_face: bool = True) -> dict:
        """JSON-ready record (``approach.json``).

        Parameters
        ----------
        per_face : bool
            Include the per-triangle arrays.

        Returns
        -------
        dict
        """
        out = {
            "target_mm": self.target_mm.tolist(),
            "faces": int(len(self.areas_mm2)),
            "skin_area_mm2": float(self.areas_mm2.sum()),
            # JSON has no infinity: a limit not set is null
            "settings": {k: (v if np.isfinite(v) else None) for k, v in self.settings.items()},
            "paa": {"score": self.score_paa, "shortest": self.shortest(paa=True)},
            "needlekit": {"score": self.score, "shortest": self.shortest()},
            "blocked": {
                "obstacle_on_line": int(self.hit.sum()),
                "leaves_body": int(self.leaves_body.sum()),
                "clearance_below_gamma": (
                    0
                    if self.clearance_mm is None
                    else int(np.sum(~self.hit & ~(self.clearance_mm >= self.settings["gamma_mm"])))
                ),
                "too_long": int(np.sum(self.length_mm > self.settings["max_length_mm"])),
                "too_oblique": int(
                    np.sum(self.normal_angle_deg > self.settings["max_normal_angle_deg"])
                ),
            },
        }
        if per_face:
            out["per_face"] = {
                "centre_mm": np.round(self.centres_mm, 4).tolist(),
                "area_mm2": np.round(self.areas_mm2, 6).tolist(),
                "length_mm": np.round(self.length_mm, 4).tolist(),
                "accessible_paa": self.accessible_paa.astype(int).tolist(),
                "accessible": self.accessible.astype(int).tolist(),
                "leaves_body": self.leaves_body.astype(int).tolist(),
                "normal_angle_deg": np.round(self.normal_angle_deg, 4).tolist(),
                "clearance_mm": (
                    None
                    if self.clearance_mm is None
                    else np.where(
                        np.isfinite(self.clearance_mm), np.round(self.clearance_mm, 4), None
                    ).tolist()
                ),
            }
        return out

    @classmethod
    def from_dict(cls, data: dict, where: str) -> ApproachAnalysis:
        """The analysis of an ``approach.json`` record, as :meth:`to_dict` writes it with
        its per-triangle arrays (rounded as the record holds them).

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.

        Returns
        -------
        ApproachAnalysis

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named), or a record written without
            its per-triangle arrays (``needlekit approach --summary-only``).
        """
        target = field_of(data, "target_mm", where, "point")
        n = field_of(data, "faces", where, "int")
        raw = field_of(data, "settings", where, "dict")
        settings = {}
        for key, unset in (("needle_radius_mm", None), ("gamma_mm", None),
                           ("max_length_mm", np.inf), ("max_normal_angle_deg", np.inf)):  # fmt: skip
            v = field_of(raw, key, f"{where}: settings", optional=unset is not None)
            settings[key] = float(unset if v is None else v)
        if "per_face" not in data:
            raise InvalidInputError(
                f"{where}: per_face",
                "missing: the record keeps no per-triangle arrays (written with "
                "--summary-only); run `needlekit approach` again without it",
            )
        per = field_of(data, "per_face", where, "dict")
        at = f"{where}: per_face"

        def column(key: str, width: int = 0, *, nulls: bool = False) -> np.ndarray:
            values = field_of(per, key, at, "list")
            if nulls:
                values = [np.nan if v is None else v for v in values]
            try:
                arr = np.asarray(values, dtype=float)
            except (TypeError, ValueError):
                arr = None
            shape = (n, width) if width else (n,)
            if arr is None or arr.shape != shape or not np.all(np.isfinite(arr) | nulls):
                what = f"{n} points" if width else f"{n} numbers"
                raise InvalidInputError(f"{at}.{key}", f"expected {what} (one per skin triangle)")
            return arr

        def flags(key: str) -> np.ndarray:
            arr = column(key)
            if not np.all((arr == 0) | (arr == 1)):
                raise InvalidInputError(f"{at}.{key}", "expected 0 or 1 per skin triangle")
            return arr.astype(bool)

        clearance = (
            None if per.get("clearance_mm", "") is None else column("clearance_mm", nulls=True)
        )
        paa = flags("accessible_paa")
        shortest = field_of(field_of(data, "needlekit", where, "dict"), "shortest",
                            f"{where}: needlekit", "dict", optional=True)  # fmt: skip
        return cls(
            target, column("centre_mm", 3), column("area_mm2"), column("length_mm"), ~paa,
            flags("leaves_body"), column("normal_angle_deg"), clearance, paa, flags("accessible"),
            settings, None if shortest is None else dict(shortest),
        )  # fmt: skip


def approach_meshes(problem, target_mm, *, max_cells: int = 200):
    """The meshes an approach analysis of a straight-needle problem runs on: its entry
    surface (the skin) and each obstacle, meshed within the needle's reach of the target
    where a surface is unbounded (:func:`reach_box`, :func:`structure_mesh`).

    Parameters
    ----------
    problem : StraightProblem
        A scenario's straight problem (its scene, entry surface and needle).
    target_mm : array_like, shape (3,)
    max_cells : int
        Marching-cubes samples along an axis for structures without a mesh file.

    Returns
    -------
    skin : trimesh.Trimesh
    obstacles : dict of str to trimesh.Trimesh
    """
    from needlekit.anatomy.scene import Role

    box = reach_box(target_mm, problem.needle.max_length_mm)
    skin = structure_mesh(problem.scene[problem.entry_surface], max_cells=max_cells, bounds=box)
    obstacles = {
        s.name: structure_mesh(s, max_cells=max_cells, bounds=box)
        for s in problem.scene.by_role(Role.OBSTACLE)
    }
    return skin, obstacles


def _mesh_arrays(mesh, name: str) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(getattr(mesh, "vertices", mesh[0] if isinstance(mesh, tuple) else None))
    f = np.asarray(getattr(mesh, "faces", mesh[1] if isinstance(mesh, tuple) else None))
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise InvalidInputError(name, "expected a triangle mesh (vertices (m, 3), faces (k, 3))")
    return np.asarray(v, dtype=float), np.asarray(f, dtype=np.int64)


def _skin_faces(skin):
    """A skin mesh's vertices, faces, triangle centres, areas and outward unit normals."""
    sv, sf = _mesh_arrays(skin, "skin")
    tri = sv[sf]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    normals = cross / np.maximum(2.0 * areas, 1e-300)[:, None]
    # outward: the signed volume of a closed outward mesh is positive
    if float(np.einsum("ij,ij->", tri[:, 0], cross)) < 0.0:
        normals = -normals
    return sv, sf, tri.mean(axis=1), areas, normals


def _obstacle_intersector(obstacles):
    from needlekit.geometry.segment_mesh import SegmentMeshIntersector

    parts = list(obstacles) if isinstance(obstacles, (list, tuple)) else [obstacles]
    verts, faces, base = [], [], 0
    for i, m in enumerate(parts):
        v, f = _mesh_arrays(m, f"obstacles[{i}]")
        verts.append(v)
        faces.append(f + base)
        base += len(v)
    if not verts:
        raise InvalidInputError("obstacles", "expected one or more obstacle meshes")
    return SegmentMeshIntersector(np.concatenate(verts), np.concatenate(faces))


def approach_analysis(
    target_mm,
    skin,
    obstacles,
    *,
    field=None,
    needle_radius_mm: float = 0.0,
    gamma_mm: float = 0.0,
    max_length_mm: float = np.inf,
    max_normal_angle_deg: float = 90.0,
    obstacle_hits=None,
    skin_hits=None,
) -> ApproachAnalysis:
    """Which skin triangles a straight needle can come from (module notes).

    Parameters
    ----------
    target_mm : array_like, shape (3,)
    skin : trimesh.Trimesh or (vertices, faces)
        The entry surface, closed, outward normals (flipped if the mesh is inside out).
    obstacles : mesh or sequence of meshes
        The obstacle models (PAA's test runs on these).
    field : DistanceField, optional
        The obstacles' signed distance, for the certified clearance (needle radius and
        gamma); without it only the lines are tested.
    needle_radius_mm, gamma_mm : float
    max_length_mm : float
    max_normal_angle_deg : float
        Largest angle between the needle and the skin's inward normal (90: no limit).
    obstacle_hits, skin_hits : SegmentMeshIntersector, optional
        Prepared intersectors (to reuse over many targets).

    Returns
    -------
    ApproachAnalysis
    """
    from needlekit.geometry.segment_mesh import SegmentMeshIntersector

    p, single = as_points(target_mm, "target_mm")
    if not single:
        raise InvalidInputError("target_mm", "expected one point (3,)")
    target = p[0]
    for name, v in (("needle_radius_mm", needle_radius_mm), ("gamma_mm", gamma_mm)):
        if not (np.isfinite(v) and v >= 0):
            raise InvalidInputError(name, f"must be a finite number >= 0, got {v!r}")
    sv, sf, centres, areas, normals = _skin_faces(skin)
    obstacle_hits = _obstacle_intersector(obstacles) if obstacle_hits is None else obstacle_hits
    skin_hits = SegmentMeshIntersector(sv, sf) if skin_hits is None else skin_hits
    n = len(sf)
    ends = np.broadcast_to(target, (n, 3))
    hit = obstacle_hits.any_hit(centres, ends)
    d = centres - target
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-300)[:, None]
    # the line from the target reaches the skin first at its own triangle
    t_first, face_first = skin_hits.first_hit(ends, centres)
    leaves = (face_first != np.arange(n)) & (t_first < 1.0 - _OWN_FACE_SLACK)
    from needlekit.geometry.so3 import angle_between  # numba: loaded when analysed

    normal_angle = np.degrees(angle_between(u, normals))
    clearance = None
    ok = ~hit & ~leaves & (length <= max_length_mm) & (normal_angle <= max_normal_angle_deg)
    if field is not None:
        from needlekit.planning.straight.cfrw import (
            CLEARANCE_CAP_ABOVE_GAMMA_MM,
            segment_clearance_bound,
        )

        clearance = np.full(n, np.nan)
        check = np.flatnonzero(~hit)
        if check.size:
            cap = needle_radius_mm + gamma_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
            b, _ = segment_clearance_bound(field, ends[check], u[check], length[check], cap_mm=cap)
            clearance[check] = b - needle_radius_mm
        ok &= clearance >= gamma_mm
    chosen = _certified_shortest(
        target, centres, length, ok, field, needle_radius_mm, gamma_mm, max_length_mm
    )
    settings = {
        "needle_radius_mm": float(needle_radius_mm),
        "gamma_mm": float(gamma_mm),
        "max_length_mm": float(max_length_mm),
        "max_normal_angle_deg": float(max_normal_angle_deg),
    }
    return ApproachAnalysis(
        target, centres, areas, length, hit, leaves, normal_angle, clearance, ~hit, ok, settings,
        chosen,
    )  # fmt: skip


def _certified_shortest(
    target, centres, length, ok, field, radius_mm, gamma_mm, max_length_mm
) -> dict | None:
    """The shortest accessible line whose needle, as recorded (points rounded), passes the
    straight clearance rule; at most RECORD_CHECK_MAX_DIRECTIONS lines are tried.

    Without a field the rule cannot be checked: with a thickness or gamma nothing is
    chosen (a constraint that cannot be checked counts as violated); with neither, the
    exact line test is the whole rule and the shortest accessible line stands.
    """
    from needlekit.planning.straight.certify import certify_segment, record_point
    from needlekit.planning.straight.entry import RECORD_CHECK_MAX_DIRECTIONS

    idx = np.flatnonzero(ok)
    idx = idx[np.argsort(length[idx], kind="stable")]
    if field is None:
        if radius_mm > 0 or gamma_mm > 0 or not idx.size:
            return None
        i = int(idx[0])
        return {"face": i, "length_mm": float(length[i]), "entry_mm": centres[i].tolist()}
    tip = record_point(target)
    for i in idx[:RECORD_CHECK_MAX_DIRECTIONS]:
        entry = record_point(centres[i])
        cert = certify_segment(field, tip, entry, radius_mm=radius_mm, gamma_mm=gamma_mm)
        if cert.passes(gamma_mm) and cert.length_mm <= max_length_mm:
            return {
                "face": int(i),
                "length_mm": cert.length_mm,
                "entry_mm": entry.tolist(),
                "clearance_mm": cert.clearance_mm,
            }
    return None


def approach_scores(targets_mm, skin, obstacles) -> np.ndarray:
    """PAA's label-wise mode: the approach score (accessible skin area fraction, PAA's
    criterion) of each target point, e.g. every voxel centre of a target label.

    Parameters
    ----------
    targets_mm : array_like, shape (k, 3)
    skin : mesh
    obstacles : mesh or sequence of meshes

    Returns
    -------
    ndarray, shape (k,)
    """
    pts, _ = as_points(targets_mm, "targets_mm")
    _, _, centres, areas, _ = _skin_faces(skin)
    hits = _obstacle_intersector(obstacles)
    total = float(areas.sum())
    out = np.empty(len(pts))
    for i, t in enumerate(pts):
        blocked = hits.any_hit(centres, np.broadcast_to(t, centres.shape))
        out[i] = float(areas[~blocked].sum()) / total
    return out


def reach_box(target_mm, max_length_mm: float) -> np.ndarray:
    """The box a straight needle of length ``max_length_mm`` ending at the target can
    come from: the part of an unbounded surface (a phantom's skin, an elliptic cylinder)
    that an approach analysis meshes.

    Parameters
    ----------
    target_mm : array_like, shape (3,)
    max_length_mm : float

    Returns
    -------
    ndarray, shape (2, 3)
    """
    t = np.asarray(target_mm, dtype=float).reshape(3)
    return np.stack([t - max_length_mm, t + max_length_mm])


def structure_mesh(structure, *, max_cells: int = 200, bounds=None):
    """A structure's surface as a triangle mesh: its mesh file when it came from one,
    else marching cubes on its field (as a segmentation becomes a model in Slicer).

    Parameters
    ----------
    structure : Structure
    max_cells : int
        Largest number of samples along an axis for marching cubes.
    bounds : array_like, shape (2, 3), optional
        The box to mesh an unbounded structure in (:func:`reach_box`); a bounded one is
        meshed whole. The faces are turned to face out of the structure (along its
        field's gradient), as a closed model's are.

    Returns
    -------
    trimesh.Trimesh
    """
    import trimesh

    from needlekit.anatomy.summary import surface_mesh

    src = Path(structure.source) if structure.source else None
    if src is not None and src.suffix.lower() in (".stl", ".obj", ".ply", ".vtk", ".off"):
        mesh = trimesh.load(src, force="mesh")
    else:
        # the structure's own field, built whole if it is not yet: a lazy field's coarse
        # preview (for figures) pools voxels and grows thin vessels by up to a coarse
        # voxel, which would block lines the segmentation leaves open
        field = structure.field.get() if isinstance(structure.field, LazyField) else structure.field
        box = field.bounds()
        unbounded = not np.all(np.isfinite(box))
        v, f = surface_mesh(field, max_cells=max_cells, bounds=bounds if unbounded else None)
        if len(f) == 0:
            why = "unbounded, and no box was given" if unbounded and bounds is None else "empty"
            raise InvalidInputError(structure.name, f"its surface could not be meshed ({why})")
        mesh = trimesh.Trimesh(v, f, process=True)
        # outward by the field (a cut-open surface has no volume to orient it by)
        grad = field.gradient(mesh.triangles_center)
        if float(np.sum(np.einsum("ij,ij->i", grad, mesh.face_normals))) < 0.0:
            mesh.invert()
        return mesh
    if mesh.volume < 0:
        mesh.invert()
    return mesh
