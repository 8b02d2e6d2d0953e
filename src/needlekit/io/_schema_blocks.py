"""The pieces of the scenario files' JSON Schema: numbers, poses and paths, the analytic
shapes, structures, the base, needle, start, goal, planner, straight and dynamic blocks.
:mod:`needlekit.io.scenario_schema` assembles them into ``SCENARIO_SCHEMA``; every field's
type, range and description is written here once.
"""

from __future__ import annotations

from typing import Any

from needlekit._numbers import MIN_POSITIVE
from needlekit.constants import (
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_MAX_LENGTH_MM,
    DEFAULT_NEEDLE_DIAMETER_MM,
    DEFAULT_R_MIN_MM,
    DEFAULT_START_EXCLUSION_MM,
)

__all__ = [
    "BASE",
    "DYNAMIC",
    "GOAL",
    "NEEDLE",
    "PLANNER",
    "PRIMITIVE_KINDS",
    "SOURCE_KINDS",
    "START",
    "STRAIGHT",
    "STRUCTURE",
]

_NUM: dict[str, Any] = {"type": "number"}
#: A positive quantity (a size, a time, a speed): at least MIN_POSITIVE of its unit (the
#: numeric gate's floor, needlekit._numbers).
_POS: dict[str, Any] = {"type": "number", "minimum": MIN_POSITIVE}
_NONNEG: dict[str, Any] = {"type": "number", "minimum": 0}
_VEC3: dict[str, Any] = {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3}
_POS3: dict[str, Any] = {"type": "array", "items": _POS, "minItems": 3, "maxItems": 3}
_ROW4: dict[str, Any] = {"type": "array", "items": _NUM, "minItems": 4, "maxItems": 4}
_POSE: dict[str, Any] = {
    "type": "array",
    "items": _ROW4,
    "minItems": 4,
    "maxItems": 4,
    "description": "4x4 homogeneous rigid transform, rows (mm); z axis = insertion direction for needle poses",
}
_PATH: dict[str, Any] = {
    "type": "string",
    "minLength": 1,
    "description": "relative to the scenario file",
}


def _obj(props: dict[str, Any], required: list[str], description: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {
        "type": "object",
        "properties": props,
        "required": required,
        "additionalProperties": False,
    }
    if description:
        out["description"] = description
    return out


#: Analytic shapes, each with its parameters (all mm) and an optional local pose.
PRIMITIVE_KINDS: dict[str, dict[str, Any]] = {
    "sphere": _obj({"center_mm": _VEC3, "radius_mm": _POS}, ["center_mm", "radius_mm"], "ball"),
    "ellipsoid": _obj(
        {"semi_axes_mm": _POS3, "pose": _POSE},
        ["semi_axes_mm"],
        "ellipsoid centred at the local origin (exact Euclidean distance)",
    ),
    "capsule": _obj(
        {"p0_mm": _VEC3, "p1_mm": _VEC3, "radius_mm": _POS},
        ["p0_mm", "p1_mm", "radius_mm"],
        "segment swept by a ball",
    ),
    "cylinder": _obj(
        {"p0_mm": _VEC3, "p1_mm": _VEC3, "radius_mm": _POS},
        ["p0_mm", "p1_mm", "radius_mm"],
        "finite cylinder, flat caps",
    ),
    "box": _obj(
        {"half_extents_mm": _POS3, "pose": _POSE},
        ["half_extents_mm"],
        "box centred at the local origin",
    ),
    "half_space": _obj(
        {"point_mm": _VEC3, "normal_mm": _VEC3},
        ["point_mm", "normal_mm"],
        "everything behind the plane through point_mm (the normal points outside)",
    ),
    "superquadric": _obj(
        {
            "semi_axes_mm": _POS3,
            "exponents": {
                "type": "array",
                "items": {"type": "number", "minimum": 2},
                "minItems": 3,
                "maxItems": 3,
            },
            "pose": _POSE,
        },
        ["semi_axes_mm", "exponents"],
        "sum_i |x_i / a_i|^e_i <= 1 in the local frame (Liu et al. 2016, Eq. 4)",
    ),
}

_MASK = _obj(
    {
        "path": _PATH,
        "label": {"type": "integer", "description": "voxel value of the structure in a label map"},
    },
    ["path"],
    "binary mask (or label map with 'label') in NIfTI (.nii, .nii.gz) or NRRD (.nrrd, .nhdr)",
)
_MESH = _obj(
    {"path": _PATH, "voxel_size_mm": _POS, "padding_mm": _NONNEG},
    ["path"],
    "closed triangle mesh (STL, OBJ, PLY, VTK) turned into a voxel signed-distance grid",
)

#: Keys that name where a structure comes from (exactly one per structure).
SOURCE_KINDS: tuple[str, ...] = ("mask", "mesh", *PRIMITIVE_KINDS)

#: An obstacle that moves during the insertion (``needlekit plan --dynamic``).
_MOVING = {
    **_obj(
        {
            "velocity_mm_s": {**_VEC3, "description": "constant drift (mm/s)"},
            "amplitude_mm": {**_VEC3, "description": "sinusoid (breathing) amplitude (mm)"},
            "period_s": {**_POS, "description": "sinusoid period (s); needs amplitude_mm"},
            "phase_deg": {**_NUM, "description": "sinusoid phase at t = 0 (deg, default 0)"},
        },
        [],
        "the obstacle moves rigidly while the needle is inserted: offset(t) = velocity_mm_s t "
        "+ amplitude_mm (sin(2 pi t / period_s + phase) - sin(phase)), with t = inserted "
        "length / dynamic.insertion_speed_mm_s; the shape as written is where it is at t = 0 "
        "(obstacles only)",
    ),
    "minProperties": 1,
}

STRUCTURE = {
    "type": "object",
    "description": "a named structure with a role and exactly one source key: "
    + ", ".join(SOURCE_KINDS),
    "properties": {
        "name": {"type": "string", "minLength": 1},
        "role": {"enum": ["obstacle", "target", "entry_surface", "allowed_region", "context"]},
        "color": {"type": "string"},
        "mask": _MASK,
        "mesh": _MESH,
        **PRIMITIVE_KINDS,
        "moving": _MOVING,
    },
    "required": ["name", "role"],
    "additionalProperties": False,
}

BASE = {
    "type": "object",
    "description": "a whole scene to start from: a built-in phantom or a Med-RAD patient (exactly one)",
    "properties": {
        "phantom": _obj(
            {
                "name": {"enum": ["lung", "liver", "neck"]},
                "seed": {"type": "integer", "minimum": 0},
                "voxel_size_mm": _POS,
                "drop": {
                    "type": "array",
                    "items": {"type": "string", "minLength": 1},
                    "uniqueItems": True,
                    "description": "names of the phantom's structures to leave out "
                    "(e.g. its vessel trees, to put other vessels in their place)",
                },
            },
            ["name"],
        ),
        "medrad": _obj(
            {
                "organ": {"enum": ["lung", "liver"]},
                "patient": {"type": "integer", "minimum": 1},
                "root": _PATH,
            },
            ["organ", "patient"],
        ),
    },
    "additionalProperties": False,
    "minProperties": 1,
    "maxProperties": 1,
}

NEEDLE = _obj(
    {
        "diameter_mm": _POS,
        "r_min_mm": _POS,
        "max_length_mm": _POS,
        "safety_margin_mm": _NONNEG,
        "max_heading_change_deg": {"type": "number", "exclusiveMinimum": 0, "maximum": 360},
        "min_puncture_angle_deg": {"type": "number", "minimum": 0, "exclusiveMaximum": 90},
        "start_exclusion_mm": _NONNEG,
    },
    [],
    "needle and its limits; defaults: "
    f"{DEFAULT_NEEDLE_DIAMETER_MM:g} mm, {DEFAULT_R_MIN_MM:g} mm, {DEFAULT_MAX_LENGTH_MM:g} mm, "
    f"0 mm, {DEFAULT_MAX_HEADING_CHANGE_DEG:g} deg, 0 deg, {DEFAULT_START_EXCLUSION_MM:g} mm",
)

START = {
    "type": "object",
    "description": "one of: pose (4x4), pose_file, case_start (name or number of a base case's start), "
    "or point_mm with an optional direction (no direction: the planner sweeps start directions)",
    "properties": {
        "pose": _POSE,
        "pose_file": _PATH,
        "case_start": {"type": ["string", "integer"]},
        "point_mm": _VEC3,
        "direction": _VEC3,
    },
    "additionalProperties": False,
    "minProperties": 1,
}

GOAL = {
    "type": "object",
    "description": "one of point_mm, point_file, case_target (a base case's target); and tolerance_mm",
    "properties": {
        "point_mm": _VEC3,
        "point_file": _PATH,
        "case_target": {"type": ["string", "integer"]},
        "tolerance_mm": _POS,
    },
    "additionalProperties": False,
    "minProperties": 1,
}

PLANNER = _obj(
    {
        "name": {
            "type": "string",
            "minLength": 1,
            "description": "a registered planner: rcs_star, rcs, rrt, or one another package registers",
        },
        "time_limit_s": _POS,
        "seed": {"type": "integer", "minimum": 0},
        "max_iterations": {"type": "integer", "minimum": 1},
        "options": {
            "type": "object",
            "description": "settings of the named planner (unknown keys are an error)",
        },
        "cost": _obj(
            {
                "kind": {"enum": ["path_length", "clearance"]},
                "weight": {"type": "number", "minimum": 0},
                "reach_mm": _POS,
            },
            ["kind"],
            "what plans minimise: path length, or the integral of the clearance cost map "
            "1 + weight * max(0, 1 - clearance / reach_mm) along the path",
        ),
    },
    [],
)

_RANGE2: dict[str, Any] = {"type": "array", "items": _NUM, "minItems": 2, "maxItems": 2}

_COVERAGE = _obj(
    {
        "zone": _obj(
            {
                "kind": {
                    "enum": ["sphere", "ellipsoid"],
                    "description": "sphere, or a spheroid whose long axis is the needle",
                },
                "length_mm": {**_POS, "description": "ellipsoid: extent along the needle"},
                "diameter_mm": {**_POS, "description": "ellipsoid: extent across the needle"},
                "radius_mm": {**_POS, "description": "sphere: its radius"},
                "tip_offset_mm": {
                    **_NONNEG,
                    "description": "zone centre this far behind the tip, toward the entry "
                    "(default 0)",
                },
            },
            ["kind"],
            "one needle's ablation zone (default ellipsoid 30 x 20 mm, an assumption)",
        ),
        "margin_mm": {**_NONNEG, "description": "ablative margin around the tumour (default 5)"},
        "max_needles": {"type": "integer", "minimum": 1, "description": "default 6"},
        "coverage_goal": {
            "type": "number",
            "exclusiveMinimum": 0,
            "maximum": 1,
            "description": "fraction of tumour-plus-margin voxels to cover (default 1)",
        },
        "structure": {
            "type": "string",
            "minLength": 1,
            "description": "the tumour structure (default the scene's first target)",
        },
        "voxel_mm": {
            **_POS,
            "description": "voxel size of a tumour given as a field (analytic, phantom); "
            "masks keep their own grid (default 1)",
        },
        "clip_to_body": {
            "type": "boolean",
            "description": "count the margin only inside the entry surface (the organ; "
            "default true)",
        },
    },
    [],
    "with targets: coverage: the ablation zone, margin, most needles, goal and tumour",
)

STRAIGHT = _obj(
    {
        "entry_surface": {
            "type": "string",
            "minLength": 1,
            "description": "structure the needles enter through (skin; a Med-RAD liver's capsule)",
        },
        "targets": {
            "anyOf": [
                {
                    "type": "array",
                    "minItems": 1,
                    "items": {"anyOf": [_VEC3, {"type": ["string", "integer"]}]},
                },
                {"const": "coverage"},
            ],
            "description": "points (mm) or targets of the base (name or number); or the string "
            "coverage: targets chosen so that ablation zones cover the tumour plus a margin "
            "(see coverage); default the goal",
        },
        "coverage": _COVERAGE,
        "gamma_mm": _NONNEG,
        "theta_range_deg": _RANGE2,
        "phi_range_deg": _RANGE2,
        "up": _VEC3,
        "max_normal_angle_deg": {**_POS, "maximum": 90},
        "approach_cone_deg": {**_POS, "maximum": 180},
        "resolution_deg": {**_POS, "maximum": 45},
        "objective": {"enum": ["min_length", "max_clearance", "min_normal_angle"]},
        "order": {
            "type": "array",
            "items": {"type": "integer", "minimum": 0},
            "uniqueItems": True,
            "description": "the needles' order: a permutation of 0..n-1 over the n targets",
        },
        "deformation": {
            "anyOf": [
                {"enum": ["none", "needle_drag"]},
                _obj({"grid": _PATH}, ["grid"], "a displacement field file (NIfTI or .npz)"),
            ]
        },
    },
    ["entry_surface"],
    "straight multi-needle planning (Liu et al. 2016): entry surface, targets, gamma, the "
    "Sigma-frame angle limits, the normal-angle limit, the approach cone around the start's "
    "reversed direction, the CFRW grid step, the objective, a fixed order, the deformation",
)

#: Planning among moving obstacles: re-plan from the tip every step (``plan --dynamic``).
DYNAMIC = _obj(
    {
        "insertion_speed_mm_s": {**_POS, "description": "constant insertion speed (mm/s)"},
        "step_mm": {**_POS, "description": "advance between re-plans (default 5)"},
        "predict": {
            "enum": ["arrival", "swept", "snapshot"],
            "description": "what each cycle plans against: each moving obstacle wherever it "
            "may be when the tip can pass a point (default), swept over the next advance, or "
            "where it is now",
        },
        "lookahead_s": {**_NONNEG, "description": "with predict: swept, how long to sweep (s)"},
    },
    [],
    "planning among the structures with a moving block: the needle advances step_mm along "
    "each cycle's plan at insertion_speed_mm_s, then plans again from its tip",
)
