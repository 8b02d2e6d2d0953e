"""Planner options: a planner's typed options dataclass filled from a mapping (a scenario's
``planner.options``, the command line's ``--option``), unknown names refused.

The registry (:mod:`needlekit.planning.registry`) and the planner interface
(:mod:`needlekit.planning.interface`, which re-exports :func:`options_from_mapping`) both
use it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from needlekit.errors import InvalidInputError, did_you_mean

__all__ = ["options_from_mapping", "refuse_unknown_options"]


def options_from_mapping(options_type: type, mapping: Mapping | Any | None, planner: str):
    """A planner's typed options from a mapping (a scenario's ``planner.options``).

    Unknown keys are an error naming them; a dataclass-typed field accepts a mapping of its
    own fields (e.g. RCS's ``resolution``).

    Parameters
    ----------
    options_type : type
        The planner's frozen options dataclass.
    mapping : mapping, options_type instance or None
    planner : str
        For error messages.

    Returns
    -------
    options_type instance

    Raises
    ------
    InvalidInputError
        Unknown keys, or values the options refuse.
    """
    if mapping is None:
        return options_type()
    if isinstance(mapping, options_type):
        return mapping
    if not isinstance(mapping, Mapping):
        raise InvalidInputError(
            "planner.options", f"{planner}: expected a mapping, got {type(mapping).__name__}"
        )
    fields = {f.name: f for f in dataclasses.fields(options_type)}
    refuse_unknown_options(planner, fields, mapping)
    values = {}
    for key, value in mapping.items():
        default = fields[key].default
        if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
            value = options_from_mapping(type(default), value, f"{planner}.{key}")
        values[key] = value
    try:
        return options_type(**values)
    except InvalidInputError as exc:
        raise InvalidInputError("planner.options", f"{planner}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise InvalidInputError("planner.options", f"{planner}: {exc}") from None


def refuse_unknown_options(planner: str, names, mapping: Mapping) -> None:
    """Refuse option names a planner does not take, naming them and the ones it does.

    Parameters
    ----------
    planner : str
        For error messages.
    names : iterable of str
        The options the planner takes.
    mapping : mapping
        The options given.

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"planner.options: <planner> takes ...; unknown: ..."``.
    """
    unknown = sorted(set(mapping) - set(names), key=str)
    if unknown:
        known = ", ".join(sorted(names)) or "no options"
        raise InvalidInputError(
            "planner.options",
            f"{planner} takes {known}; unknown: {', '.join(map(str, unknown))}"
            + (did_you_mean(str(unknown[0]), names) if len(unknown) == 1 else ""),
        )
