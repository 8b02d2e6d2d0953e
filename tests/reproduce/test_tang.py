"""``needlekit reproduce``: Tang et al.'s page, quick rows; and the study's trials with the
adaptation 2 ms off the tick against the same trials inline, the defaults' row read as the
former."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.studies.puncture_study import PunctureScenario, TrialOptions, run_puncture_trial


@pytest.fixture(scope="module")
def tang_quick(tmp_path_factory):
    """The folder of ``needlekit reproduce tang --quick`` with Eq. 3's row in one trial and
    the defaults' row in two (the study's trials 0 and 1 at seed 0), made once for the
    module."""
    import needlekit.reproduce.tang as tang

    out = tmp_path_factory.mktemp("tang")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tang, "QUICK_ROWS", {"eq3": 1, "defaults": 2})
        assert main(["reproduce", "tang", "--quick", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_tang_quick_rows(tang_quick, read_page):
    tmp_path = tang_quick
    html, doc = read_page(tmp_path, "tang")
    rows = doc["record"]["rows"]
    assert list(rows) == ["eq3", "defaults"]
    assert rows["eq3"]["summary"]["trials"] == 1 and rows["defaults"]["summary"]["trials"] == 2
    quantities = [c["quantity"] for c in doc["comparisons"]]
    for q in ("position error: mean (mm)", "position error: SD (mm)",
              "position error: range (mm)", "angle to the guide line: SD (deg)"):  # fmt: skip
        assert q in quantities
    sd = next(
        c for c in doc["comparisons"] if c["quantity"].startswith("angle to the guide line: SD")
    )
    assert "0.045 deg" in sd["note"]  # the paper's SD cannot go with its range
    assert "Tang et al., Section III-B" in html
    assert (tmp_path / "tang" / "defaults" / "puncture.html").is_file()
    d = rows["defaults"]["summary"]["position_error_mm"]
    assert d["n"] == 2 and math.isfinite(d["mean"]) and np.isfinite(d["sd"])


#: docs/control.md, the study's table (defaults, 100 trials, seed 0): position error
#: 1.63 +- 0.69 mm, angle 0.27 +- 0.139 deg. With the adaptation 2 ms late the estimate takes
#: another path to the same agreement with the sensor (within 1.5 mm and 0.5 deg before the
#: puncture), so a trial ends close to, not exactly at, where it ended inline: we allow one
#: of the study's standard deviations, the trials' own spread around their mean.
POSITION_TOLERANCE_MM = 0.69
ANGLE_TOLERANCE_DEG = 0.139


def _as_json(settings) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(settings)))


@pytest.mark.slow
def test_three_study_trials_end_alike_with_the_adaptation_2_ms_off_the_tick(tang_quick):
    """The adaptation off the tick (its schedule: tests/control/test_adaptation_schedule.py).
    Trials 0 and 1 with the default 2 ms are the reproduction's defaults' row (the study at
    seed 0 with the default options, as its record says); trial 2 is run here."""
    scenario = PunctureScenario()
    study = json.loads((tang_quick / "tang" / "defaults" / "puncture.json").read_text())
    assert study["seed"] == 0 and study["options"] == _as_json(TrialOptions())
    assert study["scenario"] == _as_json(scenario)

    def trial(i, options):  # trial i of the study at seed 0 (a seed sequence spawns once)
        return run_puncture_trial(scenario, options, i, np.random.SeedSequence(0).spawn(3)[i])

    offs = [*study["per_trial"], trial(2, TrialOptions())]
    assert [t["trial"] for t in offs] == [0, 1, 2]
    for i, off in enumerate(offs):
        inline = trial(i, TrialOptions(adaptation_delay_steps=0))
        assert (off["status"], off["reason"]) == (inline["status"], inline["reason"]), i
        assert (off["reached"], off["reached_estimated"]) == (True, True), i
        assert off["counts"]["adaptation_jobs"] == off["counts"]["needle_samples"], i
        # the same draws: target, guide line, initial estimate
        for key in ("target_mm", "guide_direction", "initial_parameters"):
            assert off[key] == inline[key], (i, key)
        d_pos = abs(off["position_error_mm"] - inline["position_error_mm"])
        d_ang = abs(off["angle_error_deg"] - inline["angle_error_deg"])
        assert d_pos <= POSITION_TOLERANCE_MM, (i, d_pos)  # measured 0.05, 0.22, 0.08 mm
        assert d_ang <= ANGLE_TOLERANCE_DEG, (i, d_ang)  # measured 0.021, 0.032, 0.0001 deg
