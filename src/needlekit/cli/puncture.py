"""``needlekit puncture``: the robotic puncture simulation study."""

from __future__ import annotations

import argparse
import math

from needlekit.cli._common import EXIT_OK, _fmt_table
from needlekit.errors import InvalidInputError

#: The puncture controller's period (ms): ``ProcedureSettings.dt_s`` (a test keeps them
#: equal), here so that the parser checks ``--adaptation-delay-ms`` without loading numpy.
CONTROL_PERIOD_MS = 1.0


def adaptation_delay_ms(text: str) -> float:
    """``--adaptation-delay-ms``: a whole number >= 0 of control periods, in ms.

    Parameters
    ----------
    text : str
        The flag's value.

    Returns
    -------
    float
        The delay (ms).

    Raises
    ------
    argparse.ArgumentTypeError
        Not a number, negative, or not a whole number of periods.
    """
    expected = f"expected a whole number >= 0 of control periods ({CONTROL_PERIOD_MS:g} ms)"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{expected}, got {text!r}") from None
    periods = v / CONTROL_PERIOD_MS
    if not (math.isfinite(v) and v >= 0 and abs(periods - round(periods)) <= 1e-9 * (1 + periods)):
        raise argparse.ArgumentTypeError(f"{expected}, got {text!r}")
    return v


def _cmd_puncture(args: argparse.Namespace) -> int:
    for name in ("history", "guide_samples"):  # before the heavy imports
        if getattr(args, name) < 0:
            raise InvalidInputError(
                name, f"expected a whole number >= 0, got {getattr(args, name)}"
            )
    from tqdm import tqdm

    from needlekit.batch import open_executor
    from needlekit.control.procedure import ProcedureSettings
    from needlekit.control.schedule import delay_steps_from_ms
    from needlekit.studies.puncture_study import (
        PunctureScenario,
        TrialOptions,
        run_puncture_study,
    )

    delay = delay_steps_from_ms(
        args.adaptation_delay_ms, ProcedureSettings().dt_s, "--adaptation-delay-ms"
    )
    options = TrialOptions(
        exact_sensors=args.exact_sensors,
        stability_radius_mm=args.stability_radius_mm,
        history_keyframes=args.history,
        guide_samples=args.guide_samples,
        clamp_vfi_rows=not args.no_vfi_clamp,
        adaptation_delay_steps=delay,
    )
    scenario = PunctureScenario(redraw_guides=not args.no_redraw)
    with (
        open_executor(args.executor, workers=args.workers, address=args.scheduler) as ex,
        tqdm(total=args.trials, desc="puncture", unit="trial", disable=None) as bar,
    ):

        def progress(trial: dict) -> None:
            bar.update(1)
            bar.set_postfix_str(f"last {trial['position_error_mm']:.2f} mm")

        study = run_puncture_study(
            args.out,
            trials=args.trials,
            seed=args.seed,
            scenario=scenario,
            options=options,
            executor=None if args.executor == "serial" else ex,
            progress=progress,
            report=not args.no_report,
        )
    s = study.summary
    rows = []
    for key in ("position_error_mm", "angle_error_deg"):
        for source, st in (("needlekit", s[key]), ("Tang et al.", s["paper"][key])):
            rows.append([f"{key}", source, st["mean"], st["sd"], st["min"], st["max"]])
    print(_fmt_table(["quantity", "source", "mean", "sd", "min", "max"], rows))
    v = s["constraint_violations"]
    print(
        f"{s['completed']} of {s['trials']} trials completed, {s['aborted']['count']} aborted; "
        f"{v['total']} constraint violations beyond the measurement noise"
    )
    if delay:
        print(
            f"adaptation off the control step, applied {s['adaptation_delay_ms']:g} ms after it starts"
        )
    r = s["reached_target"]
    print(
        f"target reached (within the target tolerance): {r['estimated']} by the robot's "
        f"estimate, {r['real']} by the real tip"
    )
    for a in s["aborted"]["trials"]:
        print(f"  trial {a['trial']}: {a['reason']}")
    for path in study.files.values():
        print(f"-> {path}")
    return EXIT_OK if s["aborted"]["count"] == 0 and v["total"] == 0 else 1
