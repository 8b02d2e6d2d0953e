"""``needlekit execute``'s target sensing on the command line: ``--sensing`` (one policy, or
several side by side) and the sensors' settings, each value checked by the numeric gates
before any work (:mod:`needlekit.execute.target_sensing`, docs/execute.md)."""

from __future__ import annotations

import argparse

from needlekit.cli._common import _positive_mm, number
from needlekit.errors import InvalidInputError

__all__ = ["SENSING_FLAGS", "add_sensing_flags", "check_sensing_flags", "sensing_policy"]

#: The policies (:data:`needlekit.execute.target_sensing.SENSING_POLICIES`, named here so
#: that the parser does not import the simulation).
POLICIES: tuple[str, ...] = ("em", "checkpoints", "tracking")

#: The sensors' flags, by argparse destination: the policy each belongs to and the field
#: of its spec it sets.
SENSING_FLAGS = {
    "checkpoint_every_mm": ("checkpoints", "every_mm"),
    "scan_s": ("checkpoints", "scan_s"),
    "confirm_scans": ("checkpoints", "confirm_scans"),
    "image_sigma_mm": ("checkpoints", "position_sigma_mm"),
    "tracking_rate_hz": ("tracking", "rate_hz"),
    "tracking_sigma_mm": ("tracking", "position_sigma_mm"),
    "tracking_latency_ms": ("tracking", "latency_s"),
}


def _policies(text: str) -> tuple[str, ...]:
    """``--sensing``: comma-separated policy names, each once."""
    names = tuple(w.strip() for w in text.split(","))
    for name in names:
        if name not in POLICIES:
            raise argparse.ArgumentTypeError(
                f"expected policies among {', '.join(POLICIES)} (comma-separated), got {name!r}"
            )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"expected each policy once, got {text!r}")
    return names


def add_sensing_flags(p: argparse.ArgumentParser) -> None:
    """Add the target-sensing flags to ``execute``'s parser.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    None
    """
    g = p.add_argument_group(
        "seeing the target: the closed loop under one sensing policy, or several side by "
        "side on the same draws (docs/execute.md)"
    )
    g.add_argument("--sensing", type=_policies, default=("em",), metavar="POLICIES",
                   help="em (the EM tip sensor only, the target assumed still; default), "
                   "checkpoints (CT scans every --checkpoint-every-mm, the needle held "
                   "--scan-s for each), tracking (the target sampled continuously); "
                   "several, comma-separated, run side by side")  # fmt: skip
    g.add_argument("--checkpoint-every-mm", type=number(1.0, 1000.0, unit="mm"), metavar="MM",
                   help="a CT checkpoint each time this much more is inserted (1-1000; "
                   "default 20)")  # fmt: skip
    g.add_argument("--confirm-scans", type=number(0, 100, integer=True), metavar="N",
                   help="confirmation scans at most when the tip believes it has arrived; "
                   "the needle goes on if one shows the target still ahead (0-100; "
                   "default 2)")  # fmt: skip
    g.add_argument("--scan-s", type=number(0.0, 3600.0, unit="s"), metavar="S",
                   help="how long the needle stands still for one scan (default 20)")  # fmt: skip
    g.add_argument("--image-sigma-mm", type=number(0.0, 10.0, unit="mm"), metavar="MM",
                   help="SD per axis of the target and the tip in a scan (default 0.5)")  # fmt: skip
    g.add_argument("--tracking-rate-hz", type=number(0.0, 1000.0, low_open=True, unit="Hz"),
                   metavar="HZ", help="target samples per second (default 10)")  # fmt: skip
    g.add_argument("--tracking-sigma-mm", type=number(0.0, 10.0, unit="mm"), metavar="MM",
                   help="SD per axis of one target sample (default 0.7)")  # fmt: skip
    g.add_argument("--tracking-latency-ms", type=number(0.0, 10000.0, unit="ms"), metavar="MS",
                   help="from a target sample's taking to its arrival (default 100)")  # fmt: skip
    g.add_argument("--retarget-mm", type=_positive_mm, metavar="MM",
                   help="re-plan to the target once it is seen this far from where the "
                   "followed plan aims (default 0.5)")  # fmt: skip


def check_sensing_flags(args: argparse.Namespace) -> None:
    """A sensor's flag only with its policy in ``--sensing``, before any work.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Named by the flag.
    """
    policies = getattr(args, "sensing", ("em",))
    for dest, (policy, _) in SENSING_FLAGS.items():
        if getattr(args, dest, None) is not None and policy not in policies:
            flag = "--" + dest.replace("_", "-")
            raise InvalidInputError(flag, f"sets the {policy} sensor: add {policy} to --sensing")
    if getattr(args, "retarget_mm", None) is not None and policies == ("em",):
        raise InvalidInputError("--retarget-mm", "applies when the target is seen: give "
                                "--sensing checkpoints or tracking")  # fmt: skip


def sensing_policy(args: argparse.Namespace):
    """The sensing policy the flags ask for (its sensors' settings; the name the first of
    ``--sensing``).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    (SensingPolicy, tuple of str)
        The policy and the names of ``--sensing``.
    """
    from dataclasses import replace

    from needlekit.execute.imaging import CheckpointSpec, TrackingSpec
    from needlekit.execute.target_sensing import SensingPolicy

    names = tuple(getattr(args, "sensing", ("em",)))
    given = {"checkpoints": {}, "tracking": {}}
    for dest, (policy, key) in SENSING_FLAGS.items():
        v = getattr(args, dest, None)
        if v is not None:
            given[policy][key] = v / 1e3 if dest == "tracking_latency_ms" else v
    policy = SensingPolicy(names[0], replace(CheckpointSpec(), **given["checkpoints"]),
                           replace(TrackingSpec(), **given["tracking"]))  # fmt: skip
    if getattr(args, "retarget_mm", None) is not None:
        policy = replace(policy, retarget_mm=args.retarget_mm)
    return policy, names
