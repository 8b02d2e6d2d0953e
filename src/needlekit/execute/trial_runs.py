"""Trials of a study run on an executor, kept as they finish, written as a signed partial
record on Ctrl-C (``puncture``, ``execute`` of a steerable plan and of a multi plan)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from needlekit.batch import SerialExecutor, as_completed_indexed
from needlekit.errors import INTERRUPT_FORMS, Interrupted, is_interrupt
from needlekit.io.partial import write_partial

__all__ = ["collect_trials"]


def collect_trials(
    trials: list,
    done: dict,
    run: Callable[[tuple], dict],
    job_of: Callable[[int], tuple],
    *,
    executor=None,
    partial_path: Path,
    head: dict,
    done_key: str,
    progress: Callable[[dict], None] | None = None,
    finish: Callable[[dict], dict] | None = None,
) -> list[dict]:
    """Run the trials not in ``done`` and return every trial's record in ``trials``' order.

    Parameters
    ----------
    trials : list of int
        The trials' numbers.
    done : dict
        Records already finished (a resumed run's), by trial; filled as trials finish.
    run : callable
        Runs one job (picklable for a process pool).
    job_of : callable
        The job of a trial number.
    executor : concurrent.futures.Executor, optional
        Default: one after another in this process.
    partial_path : Path
        The complete record's file: Ctrl-C writes the trials done beside it
        (:func:`needlekit.io.partial.partial_path`).
    head : dict
        The run's settings, written with them.
    done_key : str
        The partial record's key for the trials done.
    progress : callable, optional
        Called with each finished trial's record.
    finish : callable, optional
        Completes a record in this process as it arrives (before ``progress``).

    Returns
    -------
    list of dict

    Raises
    ------
    Interrupted
        Ctrl-C: the trials done are written marked partial, in ``trials``' order.
    """
    todo = [k for k in trials if k not in done]
    jobs = [job_of(k) for k in todo]
    try:
        for i, result in as_completed_indexed(executor or SerialExecutor(), run, jobs):
            if finish is not None:
                result = finish(result)
            done[todo[i]] = result
            if progress is not None:
                progress(result)
    except INTERRUPT_FORMS as exc:  # keep what is done, and say so
        if not is_interrupt(exc):  # Ctrl-C, also inside a compiled kernel
            raise
        kept = [done[k] for k in trials if k in done]
        written = write_partial(partial_path, {**head, done_key: kept})
        raise Interrupted(
            f"{len(kept)} of {len(trials)} trials done; written to {written} marked "
            "partial; the same command with --resume carries on"
        ) from None
    return [done[k] for k in trials]
