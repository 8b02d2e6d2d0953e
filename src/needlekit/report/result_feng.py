"""Report part of Feng et al.'s protocol on a Med-RAD lung (``feng_lungs.json`` of
``needlekit study feng-lungs``): the study's own page, drawn again from its folder.

The record holds the tables; the page's figures need each target's sweeps with every
solved path and its problem: the study writes them beside the record
(``goalN/sweep.json``, which keeps every solved plan, and ``goalN/scenario.yaml``),
located and checked by :func:`needlekit.scenario.results.read_result` before any anatomy
loads. Each sweep's summary must be the record's Table 4.
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.files import read_json_object
from needlekit.io.results import FENG_GOAL_FILES, ResultFile
from needlekit.report.result_parts import ReportPart

__all__: list[str] = []


def _feng_lungs_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.sweep_result import solved_plans_from_dict, sweeps_from_dict
    from needlekit.planning.steerable.verify import verify_plan
    from needlekit.report.feng_lungs_report import TITLE, feng_lungs_sections

    record = rf.data
    sweeps, problems = {}, {}
    for g, rec in record["goals"].items():
        scenario, sweep = (rf.path.parent / g / name for name in FENG_GOAL_FILES)
        problem = load.steerable_problem(load(scenario))
        if not np.allclose(problem.goal_mm, rec["goal_mm"], rtol=0, atol=1e-6):
            raise InvalidInputError(
                str(rf.path),
                f"the goal of {g} is not the one of {scenario}: the folder holds another run",
            )
        data = read_json_object(sweep, "sweep")
        where = f"{g}/{sweep.name}"
        found = sweeps_from_dict(data, where, goal_mm=problem.goal_mm)
        solved_plans_from_dict(found, data["solved_plans"], f"{where}: solved_plans")
        for name, sw in found.items():
            mine, theirs = rec["table4"].get(name, {}), sw.stats
            if any(mine.get(k) != theirs.get(k) for k in ("n_solved", "mean_cost_mm")):
                raise InvalidInputError(
                    str(rf.path),
                    f"Table 4 of {g} {name} is not the summary of {where}: the folder holds "
                    "another run",
                )
        sweeps[g], problems[g] = found, problem
    # every solved plan through the independent check again (as the study did)
    passed = solved = 0
    for g, found in sweeps.items():
        p = problems[g]
        for sw in found.values():
            for r in sw.results:
                if r is not None and r.status.value == "solved":
                    c = verify_plan(
                        p.with_start_pose(r.start_pose), r.plan, expected_cost_mm=r.cost_mm
                    )
                    passed, solved = passed + c.ok, solved + 1
    checks = [c for rec in record["goals"].values() for c in rec["checks"].values()]
    before = sum(c["passed"] for c in checks)
    s = record["settings"]
    return ReportPart(
        rf,
        TITLE,
        feng_lungs_sections(record, sweeps, problems, s["options"]),
        f"{len(sweeps)} targets, {s['directions']} directions, {', '.join(s['planners'])}: "
        f"{passed} of {solved} solved plans pass the independent check run again (the "
        f"study's: {before})",
        passed == solved,
    )
