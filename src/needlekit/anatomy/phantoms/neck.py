"""Neck phantom for robotic percutaneous dilatational tracheostomy (Tang et al.).

A needle is pushed along a guide line from the anterior skin of the neck, between two
tracheal rings below the thyroid isthmus, to a target in the tracheal lumen:

* ``skin`` (entry surface): the neck as an elliptic cylinder 112-130 x 104-120 mm (LR x
  AP), with the parametric skin ``S(u, v)``;
* ``trachea_lumen`` (target): the air column, a tube of the trachea's inner radius
  (outer diameter 18-22 mm, wall 2.5-3 mm), tilted 5-12 deg (lower end posterior), its
  anterior wall 14-22 mm under the skin;
* ``tracheal_rings`` (obstacle): the cricoid (a full ring) and C-shaped cartilage rings
  (open over 90 deg posteriorly, 1.6 mm thick) every 4.2-5.2 mm below it;
* ``thyroid`` (obstacle): a butterfly of two pear-shaped lobes beside the trachea (about
  50 x 20 x 20 mm) joined by an isthmus over rings 2-3;
* ``vessels`` (obstacle): common carotid arteries (6.4-8 mm), internal jugular veins
  (10-14 mm) and anterior jugular veins (3-4 mm) on both sides;
* ``oesophagus`` and ``spine`` (obstacles): behind the trachea.

The guide line passes the anterior tracheal wall in the midline between two rings below
the isthmus (tilted up to 6 deg cranio-caudally and 4 deg sideways), from its entry on
the skin to its target on the tracheal axis (Tang's target puncture position at the
middle of the cross-section, whose plane across the line guards the posterior wall).
"""

from __future__ import annotations

import functools
import time

import numpy as np

from needlekit.anatomy.phantoms._shapes import (
    AtomField,
    EllipticCylinderSkin,
    Phantom,
    assemble_scene,
    bake_structures,
    check_seed,
    check_voxel_size,
    frozen,
    pose_from_z,
    round_cone,
)
from needlekit.anatomy.phantoms._trees import chain_atoms, rotate
from needlekit.anatomy.scene import Role
from needlekit.errors import NeedlekitError

__all__ = ["DEFAULT_VOXEL_SIZE_MM", "VOXEL_SIZE_RANGE_MM", "neck_phantom"]

#: Default voxel size (mm): the guide line passes 1-1.8 mm from the rings, so the grid's
#: bound (half voxel diagonal, 0.43 mm) must stay well below that.
DEFAULT_VOXEL_SIZE_MM: float = 0.5

#: Accepted voxel sizes (mm).
VOXEL_SIZE_RANGE_MM: tuple[float, float] = (0.25, 1.0)

#: Recommended needle and limits (Tang et al.): a 14-gauge PDT needle (100 mm long,
#: 2.5 mm outer diameter); midline deviation within 30 deg and position error within
#: 5 mm clinically; the controller keeps the tip within 1.5 mm and 0.5 deg of the line.
NEEDLE = {
    "length_mm": 100.0,
    "diameter_mm": 2.5,
    "max_midline_deviation_deg": 30.0,
    "max_position_error_mm": 5.0,
    "guide_cylinder_radius_mm": 1.5,
    "guide_cone_half_angle_deg": 0.5,
}

_COLOURS = {
    "skin": "#e9c46a",
    "trachea_lumen": "#2a9d8f",
    "tracheal_rings": "#f1faee",
    "thyroid": "#bc4749",
    "vessels": "#d1495b",
    "oesophagus": "#dda15e",
    "spine": "#e9e4d4",
}

_RING_TUBE_MM = 0.8  # ring cross-section radius: 1.6 mm thick cartilage
_MAX_TRIES = 50


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _ring(centre, e_a, e_l, radius, tube, open_deg: float):
    half = np.radians(180.0 - 0.5 * open_deg)
    psi = np.linspace(-half, half, max(8, int(np.degrees(2 * half) / 10.0) + 1))
    pts = centre + radius * (np.cos(psi)[:, None] * e_a + np.sin(psi)[:, None] * e_l)
    return chain_atoms(pts, tube)


def _wiggly(rng, p0, p1, radius, n: int = 9, amp: float = 2.0):
    """A vessel from ``p0`` to ``p1`` with a smooth random lateral wiggle."""
    t = np.linspace(0.0, 1.0, n)
    phase = rng.uniform(0, 2 * np.pi, 2)
    off = amp * np.stack(
        [np.sin(2 * np.pi * t + phase[0]), np.sin(np.pi * t + phase[1]), 0.0 * t], axis=1
    )
    return chain_atoms(p0 + t[:, None] * (p1 - p0) + off, radius)


def _layout(rng):
    a = rng.uniform(56.0, 65.0)
    b = rng.uniform(52.0, 60.0)
    skin = EllipticCylinderSkin([0.0, 0.0], [a, b], np.radians([55.0, 125.0]), [-50.0, 50.0])
    tilt = np.radians(rng.uniform(5.0, 12.0))
    t_hat = np.array([0.0, np.sin(tilt), np.cos(tilt)])  # up the trachea
    e_l = np.array([1.0, 0.0, 0.0])
    e_a = np.cross(t_hat, e_l)  # anterior, perpendicular to the axis
    e_a = e_a if e_a[1] > 0 else -e_a
    r_out = 0.5 * rng.uniform(18.0, 22.0)
    r_in = r_out - rng.uniform(2.5, 3.0)
    y_t = b - rng.uniform(14.0, 22.0) - r_out
    origin = np.array([0.0, y_t, 0.0])  # axis point at z = 0

    def axis(s):
        return origin + s * t_hat

    s_cric = rng.uniform(30.0, 38.0)
    pitch = rng.uniform(4.2, 5.2)
    rings = _ring(axis(s_cric), e_a, e_l, r_out + 0.5, 2.0, 0.0)
    ring_s = []
    s = s_cric - 6.0
    while s > -55.0:
        ring_s.append(s)
        rings += _ring(axis(s), e_a, e_l, r_out - _RING_TUBE_MM, _RING_TUBE_MM, 90.0)
        s -= pitch
    lumen = AtomField([round_cone(axis(s_cric - 2.0), axis(-58.0), r_in, r_in)])
    rings_f = AtomField(rings)

    # thyroid: isthmus over rings 2-3, lobes beside the trachea
    s_isth = 0.5 * (ring_s[1] + ring_s[2])
    r_isth = rng.uniform(2.5, 3.5)
    psi = np.radians(np.linspace(-75.0, 75.0, 11))
    thyroid = []
    for ds in (-3.0, 3.0):
        arc = axis(s_isth + ds) + (r_out + 1.2 + r_isth) * (
            np.cos(psi)[:, None] * e_a + np.sin(psi)[:, None] * e_l
        )
        thyroid += chain_atoms(arc, r_isth)
    r_low, r_up = rng.uniform(8.5, 10.0), rng.uniform(5.0, 6.0)
    for side in (1.0, -1.0):
        low = axis(s_isth - 8.0) + side * (r_out + 1.5 + r_low) * e_l + 1.0 * e_a
        up = axis(s_isth + rng.uniform(26.0, 32.0)) + side * (r_out + 1.5 + r_up) * e_l - 3.0 * e_a
        thyroid.append(round_cone(low, up, r_low, r_up))
    thyroid_f = AtomField(thyroid)

    # vessels on both sides, and the structures behind the trachea
    vessels = []
    x_car = r_out + rng.uniform(12.0, 15.0)
    r_car = 0.5 * rng.uniform(6.4, 8.0)
    x_ijv = x_car + rng.uniform(9.0, 11.0)
    r_ijv = 0.5 * rng.uniform(10.0, 14.0)
    x_ajv = rng.uniform(10.0, 18.0)
    r_ajv = 0.5 * rng.uniform(3.0, 4.0)
    for side in (1.0, -1.0):
        for x, dy, r, amp in ((x_car, -6.0, r_car, 1.5), (x_ijv, -2.0, r_ijv, 2.0)):
            p0 = np.array([side * x, y_t + dy - 8.0, -62.0])
            vessels += _wiggly(rng, p0, p0 + [side * 2.0, 12.0, 124.0], r, amp=amp)
        p0 = np.array([side * x_ajv, b - 7.0 - r_ajv, -60.0])
        vessels += _wiggly(rng, p0, p0 + [side * 3.0, 0.0, 120.0], r_ajv, amp=1.0)
    vessels_f = AtomField(vessels)
    r_oes = rng.uniform(7.0, 9.0)
    oes_c = origin - (r_out + 1.5 + r_oes) * e_a + [-4.0, 0.0, 0.0]
    oesophagus = AtomField([round_cone(oes_c - 58.0 * t_hat, oes_c + 40.0 * t_hat, r_oes, r_oes)])
    r_sp = rng.uniform(11.0, 13.0)
    sp_c = oes_c - (r_oes + 3.0 + r_sp) * e_a + [4.0, 0.0, 0.0]
    spine = AtomField([round_cone(sp_c - 60.0 * t_hat, sp_c + 60.0 * t_hat, r_sp, r_sp)])
    structures = {
        "thyroid": thyroid_f,
        "vessels": vessels_f,
        "oesophagus": oesophagus,
        "spine": spine,
    }
    for name, f in structures.items():
        if float(np.max(skin.signed_distance(_surface_samples(f)))) > -3.0:
            raise NeedlekitError(f"neck phantom: {name} reaches the skin")  # pragma: no cover

    # the guide line: between two rings below the isthmus
    isth_low = s_isth - 3.0 - r_isth
    gaps = [k for k in range(len(ring_s) - 1) if 0.5 * (ring_s[k] + ring_s[k + 1]) < isth_low - 5.0]
    obstacles = [rings_f, thyroid_f, vessels_f]
    for _ in range(_MAX_TRIES):
        k = gaps[int(rng.integers(0, min(2, len(gaps))))]
        s_mid = 0.5 * (ring_s[k] + ring_s[k + 1])
        pivot = axis(s_mid) + r_out * e_a
        d = -e_a
        d = rotate(d, e_l, np.radians(rng.uniform(-6.0, 6.0)))  # cranio-caudal tilt
        d = rotate(d, t_hat, np.radians(rng.uniform(-4.0, 4.0)))  # sideways
        target = pivot + d * (((origin - pivot) @ d) + (s_mid * (t_hat @ d)))
        lo, hi = 0.0, 120.0  # back along the line to the skin
        for _i in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if skin.signed_distance(pivot - mid * d) < 0 else (lo, mid)
        entry = pivot - hi * d
        line = entry + np.linspace(0.0, 1.0, 400)[:, None] * (target - entry)
        clear = [float(f.signed_distance(line).min()) for f in obstacles]
        gap_spacing = np.linalg.norm(target - entry) / 399 / 2.0
        if (
            clear[0] - gap_spacing >= 1.0
            and clear[1] - gap_spacing >= 3.0
            and clear[2] - gap_spacing >= 5.0
        ):
            break
    else:  # pragma: no cover
        raise NeedlekitError("neck phantom: no clear guide line")
    return {
        "skin": skin,
        "trachea_lumen": lumen,
        "tracheal_rings": rings_f,
        **structures,
        "entry": entry,
        "target": target,
        "direction": d,
        "pivot": pivot,
        "interspace": (k + 1, k + 2),
        "ring_s": ring_s,
        "s_mid": s_mid,
        "t_hat": t_hat,
        "origin": origin,
        "r_out": r_out,
        "r_in": r_in,
        "pitch": pitch,
        "tilt": tilt,
        "line_clearance": dict(zip(("tracheal_rings", "thyroid", "vessels"), clear, strict=True)),
        "isthmus_s": (isth_low, s_isth + 3.0 + r_isth),
    }


def _surface_samples(field_: AtomField) -> np.ndarray:
    """Six extreme points of each end ball of the atoms (to test that a structure stays
    inside the neck)."""
    q = field_.params
    dirs = np.vstack([np.eye(3), -np.eye(3)])
    ends = ((q[:, 0:3], q[:, 6]), (q[:, 3:6], q[:, 7]))
    return np.concatenate(
        [(c[:, None, :] + r[:, None, None] * dirs[None]).reshape(-1, 3) for c, r in ends]
    )


@functools.lru_cache(maxsize=2)
def _build(seed: int, voxel_size_mm: float) -> Phantom:
    t_start = time.perf_counter()
    layout = _layout(np.random.default_rng(seed))
    t_layout = time.perf_counter() - t_start
    obstacles = ("tracheal_rings", "thyroid", "vessels", "oesophagus", "spine")
    baked, combined, timings = bake_structures(
        layout,
        bake=("tracheal_rings", "thyroid", "vessels", "trachea_lumen"),
        voxel_size_mm=voxel_size_mm,
        obstacles=obstacles,
        own_grids=True,
    )
    roles = {
        "skin": Role.ENTRY_SURFACE,
        "trachea_lumen": Role.TARGET,
        "tracheal_rings": Role.OBSTACLE,
        "thyroid": Role.OBSTACLE,
        "vessels": Role.OBSTACLE,
        "oesophagus": Role.OBSTACLE,
        "spine": Role.OBSTACLE,
    }
    scene = assemble_scene("neck", seed, roles, layout, baked, _COLOURS, combined)
    entry, target, d = layout["entry"], layout["target"], layout["direction"]
    skin = layout["skin"]
    info = {
        "voxel_size_mm": voxel_size_mm,
        "error_bound_mm": float(combined.error_bound_mm),
        "neck_semi_axes_mm": skin.semi_axes_mm.tolist(),
        "skin_u_range_rad": skin.u_range_rad.tolist(),
        "skin_v_range_mm": skin.v_range_mm.tolist(),
        "trachea_outer_diameter_mm": 2.0 * layout["r_out"],
        "trachea_inner_diameter_mm": 2.0 * layout["r_in"],
        "trachea_axis_point_mm": layout["origin"].tolist(),
        "trachea_axis_direction": layout["t_hat"].tolist(),
        "trachea_tilt_deg": float(np.degrees(layout["tilt"])),
        "ring_pitch_mm": layout["pitch"],
        "ring_count": len(layout["ring_s"]),
        "ring_thickness_mm": 2.0 * _RING_TUBE_MM,
        "ring_positions_mm": np.round(layout["ring_s"], 3).tolist(),
        "isthmus_extent_mm": list(layout["isthmus_s"]),
        "guide_line": {
            "entry_mm": entry.tolist(),
            "target_mm": target.tolist(),
            "direction": d.tolist(),
            "length_mm": float(np.linalg.norm(target - entry)),
            "interspace": list(layout["interspace"]),
            "wall_point_mm": layout["pivot"].tolist(),
            "clearance_mm": layout["line_clearance"],
            "posterior_limit_plane": {"point_mm": target.tolist(), "normal": d.tolist()},
        },
        "needle": dict(NEEDLE),
        "build_s": {"layout": t_layout, **timings, "total": time.perf_counter() - t_start},
    }
    return Phantom(
        name="neck",
        scene=scene,
        start_poses=frozen(pose_from_z(entry, d, [1.0, 0.0, 0.0])[None]),
        targets_mm=frozen(target[None]),
        entry_points_mm=frozen(entry[None]),
        seed=seed,
        info=info,
        exact_fields={n: layout[n] for n in roles},
    )


def neck_phantom(seed: int = 0, *, voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> Phantom:
    """A procedural neck for robotic percutaneous tracheostomy (module notes).

    Parameters
    ----------
    seed : int
        Seed of every random choice (>= 0); the same seed gives the same phantom.
    voxel_size_mm : float
        Voxel size (mm) of the baked rings, thyroid, vessels, lumen and obstacle union, in
        :data:`VOXEL_SIZE_RANGE_MM`.

    Returns
    -------
    Phantom
        Structures ``skin`` (entry surface), ``trachea_lumen`` (target),
        ``tracheal_rings``, ``thyroid``, ``vessels``, ``oesophagus``, ``spine``
        (obstacles); one start pose at the guide line's skin entry (z along the line),
        ``entry_points_mm`` and ``targets_mm`` its ends; ``info["guide_line"]`` with its
        interspace, clearances and the posterior limit plane.

    Raises
    ------
    InvalidInputError
        ``seed`` not a whole number >= 0, or ``voxel_size_mm`` out of range.
    """
    s = check_seed(seed)
    v = check_voxel_size(voxel_size_mm, *VOXEL_SIZE_RANGE_MM)
    return _build(s, v)
