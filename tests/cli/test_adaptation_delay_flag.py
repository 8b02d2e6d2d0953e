"""``--adaptation-delay-ms`` of ``needlekit puncture`` and ``needlekit bench control``: a
whole number of control periods, checked before any work; recorded in puncture.json."""

import json

import pytest

import needlekit.cli
from needlekit.cli import main
from needlekit.cli._parser import _build_parser


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if any command starts."""

    def started(command, args):
        raise AssertionError(f"{command} started")

    monkeypatch.setattr(needlekit.cli, "_run", started)


@pytest.mark.parametrize("command", [["puncture"], ["bench", "control"]])
@pytest.mark.parametrize("value", ["2.5", "-1", "abc", "nan", "inf", "0.5", "1e308", "2e6"])
def test_a_delay_that_is_not_whole_control_periods_is_one_error_line(
    capsys, no_work, command, value
):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--adaptation-delay-ms", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "error: argument --adaptation-delay-ms: expected a whole number >= 0 of control "
        f"periods (1 ms), at most 1e+06 ms, got '{value}'"
    ]


@pytest.mark.parametrize("command", [["puncture"], ["bench", "control"]])
def test_whole_periods_are_accepted_and_the_default_is_off_the_tick(command):
    parser = _build_parser()
    assert parser.parse_args(command).adaptation_delay_ms == 2.0
    assert parser.parse_args([*command, "--adaptation-delay-ms", "0"]).adaptation_delay_ms == 0.0
    assert parser.parse_args([*command, "--adaptation-delay-ms", "2"]).adaptation_delay_ms == 2.0
    assert parser.parse_args([*command, "--adaptation-delay-ms", "5.0"]).adaptation_delay_ms == 5.0


@pytest.mark.slow
def test_the_study_records_its_delay(puncture_trial_seed3):
    # the session's trial (tests/conftest.py): `puncture ... --adaptation-delay-ms 2`
    doc = json.loads(puncture_trial_seed3.read_text())
    assert doc["adaptation_delay_ms"] == 2.0 and doc["options"]["adaptation_delay_steps"] == 2
    (trial,) = doc["per_trial"]
    counts = trial["counts"]
    assert counts["adaptation_jobs"] == counts["needle_samples"] > 0
    assert counts["adaptation_replaced"] == 0
