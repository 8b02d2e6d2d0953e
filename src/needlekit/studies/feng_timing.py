"""How long Feng's protocol on a Med-RAD lung took, and where the time went (the
protocol at scale).

The study's planners run with wall-clock budgets (1 s per direction and planner); what is
around them (preparing the patient, sending tasks, waiting between sweeps, checking the
plans, writing the files) is waste. :func:`timing_record` sets the study's wall time
beside the bound it must keep on ``W`` workers::

    wall_s <= 1.15 * planner_s_sum / W + max(prep_s_by_worker)

(the planners' own time shared evenly, 15 % for everything else, and one preparation of
the patient per worker, which the workers do at the same time).
"""

from __future__ import annotations

__all__ = ["BOUND_FACTOR", "RCS_STAR_LIMIT_S", "timing_record", "timing_verdict"]

#: The wall time may exceed the planners' time per worker by this factor.
BOUND_FACTOR: float = 1.15
#: The RCS* part (both targets) must be done within this time (s).
RCS_STAR_LIMIT_S: float = 60.0


def timing_record(
    sweeps: dict,
    batch,
    *,
    workers: int,
    wall_s: float,
    main_prep_s: float,
    post_s: float,
    write_s: float,
    report_s: float,
    resumed: bool = False,
) -> dict:
    """The ``timing`` block of ``feng_lungs.json``.

    Parameters
    ----------
    sweeps : dict
        Per target, per planner, its SweepResult.
    batch : needlekit.planning.steerable.sweep_batch.SweepBatch
        The batch that ran them (its workers' reports and wall time).
    workers : int
        Tasks run at once (:func:`needlekit.batch.executor_workers`).
    wall_s : float
        The study, from its start (the executor open) to its last file.
    main_prep_s : float
        This process's preparation of the patient and both targets' problems.
    post_s, write_s, report_s : float
        The direct connections and the checks; writing the files; the HTML page.
    resumed : bool
        The run carried on from an interrupted one: its wall time covers only the rest,
        so the bound is not judged (``within_bound`` is None).

    Returns
    -------
    dict
        ``wall_s``, ``sweeps_wall_s``, ``planner_s_sum`` (the runs' own ``time_s``),
        ``setup_s_sum`` (each run's set-up outside its clock), ``workers``,
        ``main_prep_s``, ``prep_s_by_worker`` (per ``host:pid``; this process's own when
        the sweeps ran here), ``built_by_worker`` (kinds of what each worker built:
        ``MedradCase`` once per worker when it shares the patient), ``tasks_by_worker``,
        ``post_s``, ``write_s``, ``report_s``, ``rcs_star_wall_s`` (from the first task to
        the last RCS* run, which go first), ``rcs_star_limit_s``, ``bound_s``,
        ``within_bound`` and ``rcs_star_within_limit``.
    """
    runs = [r for by in sweeps.values() for sw in by.values() for r in sw.results if r is not None]
    planner_s = float(sum(r.time_s for r in runs))
    setup_s = float(sum(r.stats.get("setup_s", 0.0) for r in runs))
    if batch.workers:
        prep = {k: float(w["prep_s"]) for k, w in batch.workers.items()}
        built = {k: dict(w["built"]) for k, w in batch.workers.items()}
        tasks = {k: int(w["directions"]) for k, w in batch.workers.items()}
    else:  # the sweeps ran in this process, on the problems it prepared
        prep, built, tasks = {"main": float(main_prep_s)}, {}, {"main": len(runs)}
    rcs_star = [by["rcs_star"].stats["time_s"] for by in sweeps.values() if "rcs_star" in by]
    rcs_star_s = float(max(rcs_star)) if rcs_star else None
    bound = BOUND_FACTOR * planner_s / max(int(workers), 1) + max(prep.values(), default=0.0)
    return {
        "wall_s": float(wall_s),
        "sweeps_wall_s": float(batch.wall_s),
        "planner_s_sum": planner_s,
        "setup_s_sum": setup_s,
        "runs": len(runs),
        "workers": int(workers),
        "main_prep_s": float(main_prep_s),
        "prep_s_by_worker": prep,
        "built_by_worker": built,
        "tasks_by_worker": tasks,
        "post_s": float(post_s),
        "write_s": float(write_s),
        "report_s": float(report_s),
        "rcs_star_wall_s": rcs_star_s,
        "rcs_star_limit_s": RCS_STAR_LIMIT_S,
        "bound_factor": BOUND_FACTOR,
        "bound_s": float(bound),
        "resumed": bool(resumed),
        "within_bound": None if resumed else bool(wall_s <= bound),
        "rcs_star_within_limit": None if rcs_star_s is None else rcs_star_s <= RCS_STAR_LIMIT_S,
    }


def timing_verdict(t: dict) -> str:
    """The timing block in one line.

    Parameters
    ----------
    t : dict
        From :func:`timing_record`.

    Returns
    -------
    str

    Examples
    --------
    >>> t = {"wall_s": 110.0, "workers": 2, "planner_s_sum": 200.0, "bound_factor": 1.15,
    ...      "prep_s_by_worker": {"a": 1.0, "b": 1.2}, "bound_s": 116.2, "within_bound": True,
    ...      "rcs_star_wall_s": 21.0, "rcs_star_limit_s": 60.0}
    >>> timing_verdict(t)  # doctest: +NORMALIZE_WHITESPACE
    'wall time 110.0 s on 2 workers; planners 200.0 s in sum: bound 1.15 x 200.0 / 2 +
     prep 1.2 = 116.2 s, within; RCS* part 21.0 s (limit 60 s)'
    """
    prep = max(t["prep_s_by_worker"].values(), default=0.0)
    verdict = {True: "within", False: "OVER"}.get(
        t["within_bound"], "not judged (a resumed run: its wall time covers only the rest)"
    )
    line = (
        f"wall time {t['wall_s']:.1f} s on {t['workers']} worker{'s' * (t['workers'] != 1)}; "
        f"planners {t['planner_s_sum']:.1f} s in sum: bound {t['bound_factor']:g} x "
        f"{t['planner_s_sum']:.1f} / {t['workers']} + prep {prep:.1f} = {t['bound_s']:.1f} s, "
        f"{verdict}"
    )
    if t.get("rcs_star_wall_s") is not None:
        line += f"; RCS* part {t['rcs_star_wall_s']:.1f} s (limit {t['rcs_star_limit_s']:g} s)"
    return line
