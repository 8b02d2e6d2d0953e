"""``needlekit cache list|clear|limit``: what the prepared-anatomy cache holds, emptying
it, and its size limit (:mod:`needlekit.io.cache_entries`)."""

from __future__ import annotations

import argparse
import time

from needlekit.cli import _flags
from needlekit.cli._common import EXIT_OK, _fmt_table, _Parser, number
from needlekit.errors import InvalidInputError

#: ``--older-than-days``: up to a century.
_DAYS = number(0, 36500, unit="days")


def _size(text: str) -> int | None:
    """``SIZE`` of ``cache limit``: a size with its unit, or ``default``."""
    if text.strip().lower() == "default":
        return None
    from needlekit.io.cache_entries import parse_size

    try:
        return parse_size(text)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(exc.reason) from None


_size.__name__ = "size"


def _ago(seconds: float) -> str:
    """``12 s``, ``5 min``, ``3 h``, ``2 d`` (rounded down)."""
    s = max(0.0, seconds)
    for unit, n in (("d", 86400), ("h", 3600), ("min", 60)):
        if s >= n:
            return f"{int(s // n)} {unit}"
    return f"{int(s)} s"


def _limit_line(cache_dir) -> str:
    from needlekit.io.cache_entries import cache_limit, format_size

    limit, source = cache_limit(cache_dir)
    where = {"default": "the default"}.get(source, f"from {source}")
    return f"limit of {format_size(limit)} ({where})"


def _cmd_list(args: argparse.Namespace) -> int:
    from needlekit.io.anatomy_cache import cache_root
    from needlekit.io.cache_entries import being_written, cache_limit, format_size, list_entries
    from needlekit.io.files import json_text

    root = cache_root(args.cache_dir)
    limit, source = cache_limit(args.cache_dir)
    entries = list_entries(args.cache_dir)
    total = sum(e.bytes for e in entries)
    if args.json:
        out = {"cache_dir": str(root), "limit_bytes": limit, "limit_source": source,
               "total_bytes": total, "being_written_bytes": being_written(args.cache_dir),
               "entries": [e.to_dict() for e in entries]}  # fmt: skip
        print(json_text(out, "--json", indent=2))
        return EXIT_OK
    print(f"prepared-anatomy cache: {root}")
    now = time.time()
    if entries:
        rows = [[e.patient + (" (being written)" if e.writing else ""), f"{e.bytes / 1e6:.0f}",
                 _ago(now - e.created), f"{_ago(now - e.last_used)} ago", str(e.path)]
                for e in entries]  # fmt: skip
        print(_fmt_table(["patient", "size_MB", "age", "last_used", "location"], rows))
    else:
        print("no entries")
    print(f"total: {len(entries)} entr{'y' if len(entries) == 1 else 'ies'}, "
          f"{format_size(total)}, {100 * total / limit:.0f} % of the {_limit_line(args.cache_dir)}")  # fmt: skip
    writing = being_written(args.cache_dir)
    if writing:
        print(f"being written now: {format_size(writing)} (not yet an entry)")
    return EXIT_OK


def _cmd_clear(args: argparse.Namespace) -> int:
    from needlekit.io.anatomy_cache import cache_root
    from needlekit.io.cache_entries import (
        format_size,
        list_entries,
        matches,
        remove_entries,
        remove_stale,
    )

    root = cache_root(args.cache_dir)
    entries = list_entries(args.cache_dir)
    chosen = entries
    if args.patient is not None:
        chosen = [e for e in chosen if matches(e, args.patient)]
        if not chosen:
            have = ", ".join(sorted({e.patient for e in entries})) or "none"
            raise InvalidInputError(
                "--patient",
                f"expected a patient or entry key held in {root} (have: {have}), got {args.patient!r}",
            )
    if args.older_than_days is not None:
        cut = time.time() - args.older_than_days * 86400.0
        chosen = [e for e in chosen if e.last_used < cut]
    removed = remove_entries(chosen)
    remove_stale(args.cache_dir)
    size = sum(e.bytes for e in removed)
    names = "".join(f"\n  {e.patient}: {e.path}" for e in removed)
    print(f"removed {len(removed)} entr{'y' if len(removed) == 1 else 'ies'} "
          f"({format_size(size)}) from {root}{names}")  # fmt: skip
    return EXIT_OK


def _cmd_limit(args: argparse.Namespace) -> int:
    from needlekit.io.cache_entries import CACHE_LIMIT_ENV, cache_limit, make_room, set_cache_limit

    if args.size is False:  # no SIZE: say what it is
        print(_limit_line(args.cache_dir))
        return EXIT_OK
    path = set_cache_limit(args.cache_dir, args.size)
    limit, source = cache_limit(args.cache_dir)
    print(f"stored in {path}" if args.size is not None else f"removed {path}")
    print(_limit_line(args.cache_dir))
    if source == f"${CACHE_LIMIT_ENV}":
        print(f"note: ${CACHE_LIMIT_ENV} is set and takes precedence over the stored limit")
    make_room(args.cache_dir, 0, limit=limit, say=print)  # it holds no more than its limit
    return EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cache list|clear|limit`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    cache = sub.add_parser(
        "cache",
        help="list, clear or limit the prepared-anatomy cache of Med-RAD patients",
        description="The prepared-anatomy cache: Med-RAD patients prepared once (masks, "
        "fields, obstacle voxels, about 0.6-1.5 GB each) and kept for later runs.",
    )
    cache_sub = cache.add_subparsers(
        dest="cache_command", metavar="ACTION", parser_class=_Parser, required=True
    )
    cache_dir_help = ("the cache folder (default $NEEDLEKIT_CACHE_DIR, else "
                      "$XDG_CACHE_HOME/needlekit or ~/.cache/needlekit)")  # fmt: skip
    ls = cache_sub.add_parser(
        "list", help="the entries: patient, size, age, last use, location; total and limit"
    )
    _flags.CACHE_DIR.add(ls, help=cache_dir_help)
    _flags.JSON.add(ls, help="print JSON instead of a table")
    ls.set_defaults(command_handler=_cmd_list)
    clear = cache_sub.add_parser(
        "clear", help="remove every entry, or those of one patient, or those not used lately"
    )
    _flags.CACHE_DIR.add(clear, help=cache_dir_help)
    clear.add_argument(
        "--patient", metavar="NAME",
        help="only this patient's entries ('lung 1', lung1, medrad-lung1) or one entry "
        "(its folder's name or 6+ leading digits of its key)",
    )  # fmt: skip
    clear.add_argument(
        "--older-than-days", type=_DAYS, metavar="N",
        help="only entries last used more than N days ago",
    )  # fmt: skip
    clear.set_defaults(command_handler=_cmd_clear)
    limit = cache_sub.add_parser(
        "limit",
        help="show or set the size limit (default 10GB; least recently used entries go first)",
    )
    limit.add_argument(
        "size", metavar="SIZE", type=_size, nargs="?", default=False,
        help="the new limit (10GB, 500MB, 1.5TB; decimal units, GiB for 2^30) or 'default'; "
        "stored in the cache folder. $NEEDLEKIT_CACHE_LIMIT, when set, takes precedence",
    )  # fmt: skip
    _flags.CACHE_DIR.add(limit, help=cache_dir_help)
    limit.set_defaults(command_handler=_cmd_limit)
