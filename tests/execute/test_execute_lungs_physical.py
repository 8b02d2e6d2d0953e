"""``study execute-lungs --truth physical``'s plan choice: a sweep at no margin from each
start, then the margins largest first along the directions that reached. The shortcut is
checked against its oracle, full sweeps at every margin in the same order (the documented
procedure), and the plan chosen passes ``verify`` at its margin."""

from __future__ import annotations

import numpy as np
import pytest

from needlekit.planning.steerable.sweep import sphere_directions, sweep
from needlekit.planning.steerable.verify import verify_plan
from needlekit.scenario.problems import ScenarioSource
from needlekit.studies.execute_lungs_physical import (
    PhysicalLungs,
    choose_physical_plan,
    physical_scenario_document,
    physical_verdict,
)


def _problem(patient, start, margin, phys, medrad_dir):
    doc = physical_scenario_document(patient, start, margin, phys.r_min_mm, medrad_dir)
    return ScenarioSource.of_document(doc, ".", name="x.yaml").cached()[1]


@pytest.mark.slow
@pytest.mark.realdata
def test_the_plan_chosen_is_the_one_full_sweeps_at_every_margin_choose(medrad_dir):
    phys = PhysicalLungs(r_min_mm=80.0, margins_mm=(2.0, 1.0, 0.0), starts=(1, 2),
                         directions=24, max_iterations=400)  # fmt: skip
    decided, doc, res = choose_physical_plan(1, phys, medrad_dir=medrad_dir)
    oracle = None
    for margin in phys.margins_mm:
        for start in phys.starts:
            swept = sweep(_problem(1, start, margin, phys, medrad_dir), "rcs_star",
                          directions=sphere_directions(phys.directions), time_limit_s=60.0,
                          max_iterations=phys.max_iterations)  # fmt: skip
            if swept.stats["n_solved"]:
                oracle = (start, margin, float(np.min(swept.costs_mm)))
                break
        if oracle is not None:
            break
    assert oracle is not None and decided["status"] == "planned"
    # measured: one of start 1's 24 directions reaches at 80 mm, none of start 2's, and no
    # margin is kept (the choice falls through both larger margins)
    assert decided["solved_directions"] == {"1": 1, "2": 0} and oracle[:2] == (1, 0.0)
    assert (decided["start"], decided["margin_mm"]) == oracle[:2]
    assert decided["plan_cost_mm"] == pytest.approx(oracle[2], abs=1e-9)
    assert doc["needle"]["safety_margin_mm"] == oracle[1] and doc["needle"]["r_min_mm"] == 80.0
    problem = _problem(1, decided["start"], decided["margin_mm"], phys, medrad_dir)
    assert verify_plan(problem.with_free_start_direction(), res.plan).ok


def test_the_goal_is_judged_on_the_judged_policy_and_every_closed_loops_crossings():
    def run(mean, p95, violated=0):
        return {"final_error_mm": {"mean": mean, "p95": p95}, "violated": violated}

    s = {"closed_loop": run(2.0, 3.0), "crashed": [],
         "sensing": {"em": run(2.0, 3.0), "checkpoints": run(0.9, 1.9)}}  # fmt: skip
    assert physical_verdict(s, "checkpoints") == {
        "closed_mean_error_mm": True, "closed_p95_error_mm": True, "crossed": True}
    assert physical_verdict(s, "em") == {
        "closed_mean_error_mm": False, "closed_p95_error_mm": False, "crossed": True}
    s["sensing"]["em"]["violated"] = 1  # a crossing under any policy fails the goal
    assert physical_verdict(s, "checkpoints")["crossed"] is False
    assert physical_verdict(s, "tracking")["closed_mean_error_mm"] is False  # not run


@pytest.mark.parametrize("kw, field", [({"boundary": "held"}, "boundary"),
                                       ({"r_min_mm": 0.0}, "r_min_mm"),
                                       ({"margins_mm": ()}, "margins_mm"),
                                       ({"starts": (6,)}, "starts"),
                                       ({"directions": 1}, "directions")])  # fmt: skip
def test_bad_settings_name_their_field(kw, field):
    from needlekit.errors import InvalidInputError

    with pytest.raises(InvalidInputError) as exc:
        PhysicalLungs(**kw)
    assert exc.value.field == field
