"""``--option NAME=VALUE``: planner options from the command line, typed as the planner
declares them.

``NAME`` is one of the planner's options (:attr:`options_type` fields); a field of an option
that has fields of its own (RCS's ``resolution``) is ``OPTION.FIELD``, e.g.
``resolution.max_length_mm=8``. ``VALUE`` is read by the declared type
(:func:`needlekit.planning.registry.option_types`, which needs no planner module):
``int`` a whole number, ``float`` a number, ``bool`` true/false (yes/no, on/off, 1/0),
``str`` the text, ``tuple`` whole numbers separated by commas. An unknown name or a value
that is not of its type is refused here, in one line naming the flag, before any planner
module (numba) is imported; the planner's options check the values themselves (ranges)
when it is built.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from needlekit._numbers import ANY_INT, ANY_REAL, Bounds, field_bounds
from needlekit.errors import InvalidInputError, did_you_mean

_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


def _typed(kind, text: str, name: str = ""):
    """``text`` read as ``kind``; ValueError saying what was expected. A number passes the
    gate (:mod:`needlekit._numbers`): finite, within the bound of its unit (``name``'s
    ending, e.g. ``max_length_mm``) or the general one."""
    if kind is bool:
        if text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        raise ValueError(f"expected true or false, got {text!r}")
    if kind is int:
        try:
            v = int(text)
        except ValueError:
            raise ValueError(f"expected a whole number, got {text!r}") from None
        return _gated(v, ANY_INT, text)
    if kind is float:
        try:
            v = float(text)
        except ValueError:
            raise ValueError(f"expected a number, got {text!r}") from None
        return _gated(v, field_bounds(name) or ANY_REAL, text)
    if kind is tuple:
        try:
            return tuple(_gated(int(p), ANY_INT, text) for p in text.replace(",", " ").split())
        except ValueError:
            raise ValueError(f"expected whole numbers separated by commas, got {text!r}") from None
    return text


def _gated(value, bounds: Bounds, text: str):
    """``value`` if the gate lets it through; ValueError saying the range otherwise."""
    if not bounds.contains(value):
        raise ValueError(f"expected {bounds}, got {text!r}")
    return value


def _one(planner: str, types: Mapping, name: str, text: str):
    """``(option, value)`` for ``--option name=text`` of one planner; ``value`` is a dict of
    one field for ``OPTION.FIELD``. KeyError: the planner has no such option."""
    head, dot, field = name.partition(".")
    if head not in types:
        raise KeyError(head)
    kind = types[head]
    flag = f"--option {name}"
    if isinstance(kind, Mapping):
        if not dot:
            fields = ", ".join(kind)
            raise InvalidInputError(
                flag, f"{planner}'s {head} has fields: give {head}.FIELD=VALUE ({fields})"
            )
        if field not in kind:
            raise InvalidInputError(
                flag, f"{planner}'s {head} has {', '.join(kind)}; unknown: {field}"
            )
        kind = kind[field]
    elif dot:
        raise InvalidInputError(flag, f"{planner}'s {head} has no fields")
    try:
        value = _typed(kind, text, field or head)
    except ValueError as exc:
        raise InvalidInputError(flag, f"{planner}: {exc}") from None
    return head, ({field: value} if dot else value)


def planner_flag_options(
    pairs: Sequence[tuple[str, str]] | None, planners: Sequence[str]
) -> dict[str, dict]:
    """Per planner, the options ``--option`` gives it, typed and their names checked.

    Each option goes to every planner of ``planners`` that has it (a sweep comparing
    several planners); one that none of them has is an error.

    Parameters
    ----------
    pairs : sequence of (str, str) or None
        ``(NAME, VALUE)`` as the parser read them, in order (a later one wins).
    planners : sequence of str
        Registered planner names.

    Returns
    -------
    dict
        Planner name -> ``{option: value}``; a dataclass-typed option's value is a dict of
        the fields given.

    Raises
    ------
    InvalidInputError
        ``--option NAME: ...``: an unknown name, a value not of its type.
    """
    from needlekit.planning.registry import option_types

    types = {p: option_types(p) for p in planners}
    out: dict[str, dict] = {p: {} for p in planners}
    for name, text in pairs or ():
        taken = False
        for planner in planners:
            try:
                head, value = _one(planner, types[planner], name, text)
            except KeyError:
                continue
            taken = True
            opts = out[planner]
            if isinstance(value, dict):
                opts[head] = {**opts.get(head, {}), **value}
            else:
                opts[head] = value
        if not taken:
            known = "; ".join(f"{p} takes {', '.join(types[p]) or 'no options'}" for p in planners)
            hint = did_you_mean(name.partition(".")[0], {o for p in planners for o in types[p]})
            raise InvalidInputError(f"--option {name}", f"unknown option ({known}){hint}")
    return out
