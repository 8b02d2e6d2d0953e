"""The JSON Schema of needlekit scenario files (``needlekit schema`` prints it), and the
reading and validation of a scenario document against it.

Written once here; every file is validated against it before anything is built
(:func:`read_scenario_document`, :func:`validate_scenario_document`), and
:mod:`needlekit.scenario.loading` adds the checks a schema cannot express (exactly one source
per structure, unique names, files that exist, a 4x4 rigid pose).

This module is light on purpose: it imports neither numpy nor the anatomy (numba), and
``jsonschema`` and ``yaml`` only when a document is read, so that the command line answers
a bad scenario file at once.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path
from typing import Any

from needlekit.anatomy.collision_registry import check_collision_model
from needlekit.constants import (
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_MAX_LENGTH_MM,
    DEFAULT_NEEDLE_DIAMETER_MM,
    DEFAULT_R_MIN_MM,
    DEFAULT_START_EXCLUSION_MM,
)
from needlekit.errors import InvalidInputError

__all__ = [
    "PRIMITIVE_KINDS",
    "SCENARIO_SCHEMA",
    "SCENARIO_VERSION",
    "SOURCE_KINDS",
    "ScenarioDocument",
    "checked_document",
    "read_scenario_document",
    "validate_scenario_document",
]

SCENARIO_VERSION = 1

_NUM: dict[str, Any] = {"type": "number"}
_POS: dict[str, Any] = {"type": "number", "exclusiveMinimum": 0}
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

_STRUCTURE = {
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

_BASE = {
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

_NEEDLE = _obj(
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

_START = {
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

_GOAL = {
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

_PLANNER = _obj(
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

_STRAIGHT = _obj(
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
        "max_normal_angle_deg": _POS,
        "approach_cone_deg": _POS,
        "resolution_deg": _POS,
        "objective": {"enum": ["min_length", "max_clearance", "min_normal_angle"]},
        "order": {"type": "array", "items": {"type": "integer", "minimum": 0}},
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
_DYNAMIC = _obj(
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

#: The JSON Schema (draft 2020-12) of a scenario file.
SCENARIO_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://needlekit.dev/schema/scenario-1.json",
    "title": "needlekit scenario",
    "description": "Anatomy, needle, start, goal and planner settings of a needle-insertion problem. "
    "Units: mm and degrees as the field names say; coordinates in the file's frame (RAS unless frame: LPS).",
    "type": "object",
    "properties": {
        "version": {"const": SCENARIO_VERSION},
        "name": {"type": "string"},
        "description": {"type": "string"},
        "frame": {"enum": ["RAS", "LPS"], "description": "frame of every coordinate in the file"},
        "base": _BASE,
        "structures": {"type": "array", "items": _STRUCTURE},
        "needle": _NEEDLE,
        "start": _START,
        "goal": _GOAL,
        "planner": _PLANNER,
        "straight": _STRAIGHT,
        "dynamic": _DYNAMIC,
        "collision_model": {
            "type": "string",
            "pattern": "^[A-Za-z_][A-Za-z0-9_]*$",
            "description": "how collisions are decided: a registered collision checker's name; "
            "built in: field (the scene's distance field, certified: its error bound "
            "subtracted) and voxel_centres (the reference planner's exact test against obstacle "
            "voxel centres; needs a Med-RAD base); default field",
        },
        "collision_options": {
            "type": "object",
            "description": "settings handed to the collision checker's factory (its own)",
        },
    },
    "required": ["version"],
    "additionalProperties": False,
}


# ----------------------------------------------------------------------------------------
# validation


@cache
def _validator():
    import jsonschema

    return jsonschema.Draft202012Validator(SCENARIO_SCHEMA)


def _where(path) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _schema_message(err) -> tuple[str, str]:
    """Where a ``jsonschema.ValidationError`` is, and what was expected, in one line."""
    where = _where(err.absolute_path)
    v = err.validator
    if v == "additionalProperties":
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        allowed = ", ".join(err.schema.get("properties", {}))
        return where, f"unknown field {', '.join(map(repr, extra))} (allowed: {allowed})"
    if v == "required":
        return where, err.message.replace("is a required property", "is missing")
    if v == "enum":
        return (
            where,
            f"expected one of {', '.join(map(str, err.validator_value))}, got {err.instance!r}",
        )
    if v == "const":
        return where, f"expected {err.validator_value!r}, got {err.instance!r}"
    if v == "type":
        want = err.validator_value
        want = " or ".join(want) if isinstance(want, list) else want
        return where, f"expected {want}, got {type(err.instance).__name__} {err.instance!r:.60}"
    if v in ("minItems", "maxItems"):
        return (
            where,
            f"expected {err.schema.get('minItems')} to {err.schema.get('maxItems')} items, got {len(err.instance)}",
        )
    bounds = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}
    if v in bounds:
        return where, f"expected a number {bounds[v]} {err.validator_value:g}, got {err.instance!r}"
    if v in ("minProperties", "maxProperties"):
        keys = ", ".join(err.schema.get("properties", {}))
        n = err.schema.get("maxProperties")
        return where, f"expected {'exactly one' if n == 1 else 'at least one'} of {keys}"
    return where, err.message


def validate_scenario_document(data: Any, source: str) -> None:
    """Check a parsed scenario document against :data:`SCENARIO_SCHEMA`.

    Parameters
    ----------
    data : object
        The parsed YAML or JSON document.
    source : str
        Names the document in the message (usually the file name).

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"<source>: <field>: <what was expected>"`` for the most relevant error.
    """
    import jsonschema

    errors = sorted(
        _validator().iter_errors(data),
        key=lambda e: (len(e.absolute_path), list(map(str, e.absolute_path))),
    )
    if errors:
        best = jsonschema.exceptions.best_match(errors)
        where, msg = _schema_message(best)
        raise InvalidInputError(f"{source}: {where}", msg)
    if isinstance(data, dict) and "collision_model" in data:
        # a registered checker's name (the registry is light: no kernel loads)
        try:
            check_collision_model(data["collision_model"])
        except InvalidInputError as exc:
            raise InvalidInputError(f"{source}: collision_model", exc.reason) from None


class ScenarioDocument(dict):
    """A scenario document that has been checked against the schema (what
    :func:`read_scenario_document` returns): passed down through a command, it is not read
    or checked again (:func:`needlekit.scenario.loading.parse_scenario` checks a plain
    ``dict``, not this). Treat it as read-only: a changed document is a plain ``dict``
    again (``dict(doc)``) and is checked anew.

    Parameters
    ----------
    data : dict
        A document :func:`validate_scenario_document` accepted.
    source : str
        The name it was checked under (the file name).
    """

    def __init__(self, data: dict, source: str) -> None:
        super().__init__(data)
        self.source = source


def checked_document(data: Any, source: str) -> ScenarioDocument:
    """``data`` checked against the schema, once: a :class:`ScenarioDocument` is returned
    as it is, anything else validated (:func:`validate_scenario_document`).

    Parameters
    ----------
    data : object
        A parsed document.
    source : str
        Names it in messages.

    Returns
    -------
    ScenarioDocument

    Raises
    ------
    InvalidInputError
        As :func:`validate_scenario_document`.
    """
    if isinstance(data, ScenarioDocument):
        return data
    validate_scenario_document(data, source)
    return ScenarioDocument(data, source)


def read_scenario_document(path: str | os.PathLike) -> ScenarioDocument:
    """Read and validate a scenario file's document, without building its anatomy (cheap:
    callers check settings such as the planner block before any long computation).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    ScenarioDocument
        The document, valid against the schema.

    Raises
    ------
    InvalidInputError
        Missing or unreadable file, bad YAML, or a field not as the schema says.
    """
    import yaml

    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(str(p), "scenario file not found")
    try:
        text = p.read_text(encoding="utf-8")
        data = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(str(p), f"cannot read the file ({exc})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise InvalidInputError(str(p), f"invalid YAML{at}: {problem}") from None
    if not isinstance(data, dict):
        raise InvalidInputError(
            str(p), f"expected a mapping at the top level, got {type(data).__name__}"
        )
    return checked_document(data, p.name)
