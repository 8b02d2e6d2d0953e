"""YAML read within bounds: nesting depth and the number of values after aliases expand.

``yaml.safe_load`` builds no objects from tags, but two hostile documents still hurt it: a
list nested hundreds deep overflows the recursion of its composer (a traceback), and a
"billion laughs" document, a few lines of anchors each used nine times by the next, is a
few hundred bytes that every reader which walks it (the schema check, a copy written beside
the results) expands to hundreds of millions of values. :func:`load_bounded` first walks
the parser's events, which needs no recursion, counting the depth and the values each
anchor stands for; only a document within both bounds is then loaded. The walk takes
about as long as parsing does: well under a second for any document it refuses.
"""

from __future__ import annotations

import re

__all__ = ["MAX_DEPTH", "MAX_VALUES", "YamlBoundsError", "load_bounded"]

#: Deepest nesting of lists and mappings a document may have (a scenario uses five or so).
MAX_DEPTH: int = 64

#: Most values (scalars, lists, mappings) a document may stand for, aliases expanded.
MAX_VALUES: int = 1_000_000


class YamlBoundsError(ValueError):
    """A document past :data:`MAX_DEPTH` or :data:`MAX_VALUES`; ``line`` is 1-based."""

    def __init__(self, message: str, line: int) -> None:
        super().__init__(message)
        self.line = line


def load_bounded(text: str, *, max_depth: int = MAX_DEPTH, max_values: int = MAX_VALUES):
    """``yaml.safe_load(text)`` for a document within the bounds.

    Parameters
    ----------
    text : str
    max_depth : int
        Deepest nesting allowed.
    max_values : int
        Most values allowed, each alias counted as everything its anchor stands for.

    Returns
    -------
    object
        The loaded document.

    Raises
    ------
    YamlBoundsError
        Past a bound (before anything is built).
    yaml.YAMLError
        Not YAML.

    Examples
    --------
    >>> load_bounded("a: &x [1, 2]\\nb: *x")
    {'a': [1, 2], 'b': [1, 2]}
    >>> load_bounded("[1e3, 2.5E-1, 7, 1.5]")  # exponent forms are numbers, as in JSON
    [1000.0, 0.25, 7, 1.5]
    >>> try:
    ...     load_bounded("[[[1]]]", max_depth=2)
    ... except YamlBoundsError as exc:
    ...     print(exc)
    is nested deeper than 2 levels
    """
    import yaml

    _check_events(yaml.parse(text, Loader=yaml.SafeLoader), max_depth, max_values)
    return yaml.load(text, Loader=_loader())


#: Numbers in exponent form that YAML 1.1 (PyYAML's resolver) reads as text but YAML 1.2
#: and JSON read as numbers: ``1e308``, ``2E-3``, ``1.5e3`` (1.1 wants a dot and a sign).
_EXPONENT_FLOAT = r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"

_LOADER = None


def _loader():
    """``yaml.SafeLoader`` that also reads exponent-form numbers as floats."""
    global _LOADER
    if _LOADER is None:
        import yaml

        class Loader(yaml.SafeLoader):
            pass

        Loader.yaml_implicit_resolvers = {
            k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
        }
        Loader.add_implicit_resolver(
            "tag:yaml.org,2002:float", re.compile(_EXPONENT_FLOAT), list("-+0123456789.")
        )
        _LOADER = Loader
    return _LOADER


def _check_events(events, max_depth: int, max_values: int) -> None:
    import yaml

    stack: list[list] = []  # per open list or mapping: [anchor, values so far]
    anchors: dict[str, int] = {}
    total = 0
    for ev in events:
        line = ev.start_mark.line + 1 if ev.start_mark is not None else 0
        if isinstance(ev, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            if len(stack) >= max_depth:
                raise YamlBoundsError(f"is nested deeper than {max_depth} levels", line)
            stack.append([ev.anchor, 1])
            continue
        if isinstance(ev, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            anchor, n = stack.pop()
            if anchor is not None:
                anchors[anchor] = n
        elif isinstance(ev, yaml.ScalarEvent):
            n = 1
            if ev.anchor is not None:
                anchors[ev.anchor] = 1
        elif isinstance(ev, yaml.AliasEvent):
            n = anchors.get(ev.anchor, 1)  # an unknown alias: safe_load names it
        else:
            continue
        if stack:
            stack[-1][1] += n
            n = stack[-1][1]
        else:
            total += n
            n = total
        if n > max_values:
            raise YamlBoundsError(
                f"stands for more than {max_values:,} values once its aliases are expanded",
                line,
            )
