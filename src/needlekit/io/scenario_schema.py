"""The JSON Schema of needlekit scenario files (``needlekit schema`` prints it), and the
reading and validation of a scenario document against it.

Assembled here from its pieces (:mod:`needlekit.io._schema_blocks`, where each field is
written once); every file is validated against it before anything is built
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

from needlekit._numbers import MAX_ABS_MM, check_document
from needlekit.anatomy.collision_registry import check_collision_model
from needlekit.errors import InvalidInputError, did_you_mean
from needlekit.io import safe_yaml
from needlekit.io._schema_blocks import (  # the schema's pieces; the kinds re-exported
    BASE,
    DYNAMIC,
    GOAL,
    NEEDLE,
    PLANNER,
    PRIMITIVE_KINDS,
    SOURCE_KINDS,
    START,
    STRAIGHT,
    STRUCTURE,
)
from needlekit.io.files import _undecodable, without_content
from needlekit.plausibility import document_warnings, warn

__all__ = [
    "MAX_ABS_MM",
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
        "base": BASE,
        "structures": {"type": "array", "items": STRUCTURE},
        "needle": NEEDLE,
        "start": START,
        "goal": GOAL,
        "planner": PLANNER,
        "straight": STRAIGHT,
        "dynamic": DYNAMIC,
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


def _key(part) -> str:
    """A mapping key as a message shows it: as written, or quoted when it holds line breaks
    or other unprintable characters (the message stays one line)."""
    text = str(part)
    return text if text.isprintable() else repr(text)


def _where(path) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{_key(part)}" if out else _key(part))
    return out or "(top level)"


def _schema_message(err) -> tuple[str, str]:
    """Where a ``jsonschema.ValidationError`` is, and what was expected, in one line."""
    where = _where(err.absolute_path)
    v = err.validator
    if v == "additionalProperties":
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        known = list(err.schema.get("properties", {}))
        hint = did_you_mean(extra[0], known) if len(extra) == 1 else ""
        return where, f"unknown field {', '.join(map(repr, extra))} (allowed: {', '.join(known)}){hint}"
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

    _refuse_non_finite(data, source)
    errors = sorted(
        _validator().iter_errors(data),
        key=lambda e: (len(e.absolute_path), list(map(str, e.absolute_path))),
    )
    if errors:
        best = jsonschema.exceptions.best_match(errors)
        where, msg = _schema_message(best)
        raise InvalidInputError(f"{source}: {where}", msg)
    _check_relations(data, source)
    warn(document_warnings(data), source)
    if isinstance(data, dict) and "collision_model" in data:
        # a registered checker's name (the registry is light: no kernel loads)
        try:
            check_collision_model(data["collision_model"])
        except InvalidInputError as exc:
            raise InvalidInputError(f"{source}: collision_model", exc.reason) from None


def _check_relations(data: Any, source: str) -> None:
    """What the schema cannot say and the planners would refuse only after the anatomy is
    loaded: directions that are vectors, a needle order that is a permutation (of the
    targets listed, when they are)."""
    if not isinstance(data, dict):
        return
    straight = data.get("straight") if isinstance(data.get("straight"), dict) else {}
    for where, vec in (
        ("start.direction", (data.get("start") or {}).get("direction")),
        ("straight.up", straight.get("up")),
    ):
        # the planners' rule: no component above 1e-12 is no direction
        if isinstance(vec, list) and not max(abs(float(v)) for v in vec) > 1e-12:
            raise InvalidInputError(f"{source}: {where}", f"expected a non-zero vector, got {vec}")
    order = straight.get("order")
    if isinstance(order, list):
        targets = straight.get("targets")
        # the targets listed; one (the goal) when none are; coverage's are known later
        n = len(targets) if isinstance(targets, list) else 1 if targets is None else len(order)
        if sorted(order) != list(range(n)):
            listed = "the targets" if targets != "coverage" else "its own length"
            raise InvalidInputError(
                f"{source}: straight.order",
                f"expected a permutation of 0..{n - 1} ({listed}), got {order}",
            )


def _refuse_non_finite(data: Any, source: str) -> None:
    """No NaN or infinity anywhere in a document (YAML's ``.nan``, ``.inf``; numbers past
    the float range such as ``1e999``), and every number within its field's bound (a length
    within :data:`MAX_ABS_MM`): the one gate, :func:`needlekit._numbers.check_document`,
    before the schema looks."""
    check_document(data, source)


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
        data = safe_yaml.load_bounded(text)
    except UnicodeDecodeError as exc:
        raise InvalidInputError(str(p), f"not UTF-8 text ({_undecodable(exc)})") from None
    except OSError as exc:
        raise InvalidInputError(str(p), f"cannot read the file ({exc.strerror or exc})") from None
    except safe_yaml.YamlBoundsError as exc:
        raise InvalidInputError(str(p), f"refused at line {exc.line}: the document {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = without_content(getattr(exc, "problem", None) or "invalid YAML")
        raise InvalidInputError(str(p), f"invalid YAML{at}: {problem}") from None
    if data is None:
        raise InvalidInputError(str(p), "the file is empty: expected a scenario mapping")
    if not isinstance(data, dict):
        raise InvalidInputError(
            str(p), f"expected a mapping at the top level, got {type(data).__name__}"
        )
    return checked_document(data, p.name)
