"""``needlekit puncture``: the robotic puncture simulation study."""

from __future__ import annotations

import argparse

from needlekit._numbers import Bounds
from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _count,
    _fmt_table,
    _non_negative_mm,
    _Number,
    _positive_int,
)
from needlekit.errors import InvalidInputError

#: What ``needlekit puncture`` writes in its --out folder.
PUNCTURE_FILES = ("puncture.json", "puncture.html")

#: The puncture controller's period (ms): ``ProcedureSettings.dt_s`` (a test keeps them
#: equal), here so that the parser checks ``--adaptation-delay-ms`` without loading numpy.
CONTROL_PERIOD_MS = 1.0
#: The default ``--adaptation-delay-ms``: ``DEFAULT_ADAPTATION_DELAY_STEPS`` control
#: periods (:mod:`needlekit.control.schedule`; a test keeps them equal).
DEFAULT_ADAPTATION_DELAY_MS = 2.0


class _ControlPeriods(_Number):
    """``--adaptation-delay-ms``: the gate's range (:data:`MAX_DELAY_MS`), and a whole
    number of control periods (:data:`CONTROL_PERIOD_MS`)."""

    def _expected(self) -> str:
        return (
            f"expected a whole number >= 0 of control periods ({CONTROL_PERIOD_MS:g} ms), "
            f"at most {self.bounds.high:g} ms"
        )

    def __call__(self, text: str) -> float:
        v = super().__call__(text)
        periods = v / CONTROL_PERIOD_MS
        if abs(periods - round(periods)) > 1e-9 * (1 + periods):
            raise argparse.ArgumentTypeError(f"{self._expected()}, got {text!r}")
        return v


#: Longest adaptation delay (ms): 1000 s, longer than any trial (the adaptation then never
#: runs).
MAX_DELAY_MS = 1e6
#: The type of ``--adaptation-delay-ms``: a whole number >= 0 of control periods, in ms;
#: argparse.ArgumentTypeError when not.
adaptation_delay_ms = _ControlPeriods(Bounds(0.0, MAX_DELAY_MS, unit="ms"))


#: ``--adaptation-delay-ms`` of ``puncture`` and ``bench control``.
ADAPTATION_DELAY_MS = _flags.Flag(
    "--adaptation-delay-ms",
    {"type": adaptation_delay_ms, "default": DEFAULT_ADAPTATION_DELAY_MS, "metavar": "MS"},
)


#: ``--qp-solver`` of ``puncture`` and ``bench control``.
QP_SOLVER = _flags.Flag("--qp-solver", {"default": "daqp", "metavar": "NAME"})


def _cmd_puncture(args: argparse.Namespace) -> int:
    for name in ("history", "guide_samples"):  # before the heavy imports
        if getattr(args, name) < 0:
            raise InvalidInputError(
                name, f"expected a whole number >= 0, got {getattr(args, name)}"
            )
    from needlekit.control.qp_registry import check_qp_solver

    check_qp_solver(args.qp_solver, "--qp-solver")  # by name, before the heavy imports
    from tqdm import tqdm

    from needlekit.batch import open_executor
    from needlekit.control.procedure import ProcedureSettings
    from needlekit.control.qp_registry import get_qp_solver
    from needlekit.control.schedule import delay_steps_from_ms
    from needlekit.studies.puncture_study import (
        PunctureScenario,
        TrialOptions,
        read_partial_puncture,
        run_puncture_study,
    )

    delay = delay_steps_from_ms(
        args.adaptation_delay_ms, ProcedureSettings().dt_s, "--adaptation-delay-ms"
    )
    get_qp_solver(args.qp_solver)  # an unknown name or a missing extra: before any trial
    options = TrialOptions(
        exact_sensors=args.exact_sensors,
        stability_radius_mm=args.stability_radius_mm,
        history_keyframes=args.history,
        guide_samples=args.guide_samples,
        clamp_vfi_rows=not args.no_vfi_clamp,
        adaptation_delay_steps=delay,
        qp_solver=args.qp_solver,
    )
    scenario = PunctureScenario(redraw_guides=not args.no_redraw)
    resume = None
    if args.resume:  # the partial file agrees with this run, before any trial
        resume = read_partial_puncture(
            args.out, trials=args.trials, seed=args.seed, scenario=scenario, options=options
        )
    with (
        open_executor(
            args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
        ) as ex,
        tqdm(
            total=args.trials,
            initial=len(resume or ()),
            desc="puncture",
            unit="trial",
            disable=None,
        ) as bar,
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
            resume=resume,
        )
    s = study.summary
    rows = []
    for key, what, unit in (("position_error_mm", "position error", "mm"),
                            ("angle_error_deg", "angle error", "deg")):  # fmt: skip
        for source, st in (("needlekit", s[key]), ("Tang et al.", s["paper"][key])):
            rows.append([what, unit, source, st["mean"], st["sd"], st["min"], st["max"]])
    no_trial = "no trial completed, so there is no error to measure"
    print(_fmt_table(["quantity", "unit", "source", "mean", "sd", "min", "max"], rows,
                     why=dict.fromkeys(("mean", "sd", "min", "max"), no_trial)))  # fmt: skip
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


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``puncture`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    pu = sub.add_parser(
        "puncture",
        help="simulate robotic punctures with adaptive VFI control (Tang et al., Section III)",
        description="Run simulated punctures of a Panda guided by EM sensors under kinematic "
        "uncertainty and write DIR/puncture.json and DIR/puncture.html; exit 1 when a trial "
        "aborted or a constraint was violated beyond the measurement noise, else 0.",
    )
    pu.add_argument("--trials", type=_positive_int, default=100, help="trials (default 100)")
    _flags.SEED.add(pu, default=0, help="root seed (default 0)")
    _flags.OUT.add(
        pu,
        folder=True,
        contents=PUNCTURE_FILES,
        default="out/puncture",
        help="output folder (default out/puncture)",
    )
    pu.add_argument(
        "--exact-sensors", action="store_true", help="noise-free EM sensors (rate and latency kept)"
    )
    pu.add_argument(
        "--stability-radius-mm",
        type=_non_negative_mm,
        default=1.5,
        help="ball in which the adaptation may grow the task error (0: the paper's row; "
        "default 1.5)",
    )
    pu.add_argument(
        "--history",
        type=_count,
        default=40,
        metavar="KEYFRAMES",
        help="measurement keyframes in the adaptation objective (0: the newest alone; default 40)",
    )
    pu.add_argument(
        "--guide-samples",
        type=_count,
        default=1,
        metavar="N",
        help="bronchoscope samples averaged into the guide line (default 1: one noisy "
        "measurement, the paper's simulation; 100: 1 s at 100 Hz as its mannequin trials; "
        "0: every sample of the trial, running)",
    )
    pu.add_argument(
        "--no-vfi-clamp",
        action="store_true",
        help="the adaptation's VFI rows as the VFI law writes them (default: never pull the "
        "estimate back into a constraint it violates)",
    )
    pu.add_argument(
        "--no-redraw",
        action="store_true",
        help="keep each trial's first guide-line draw (default: redraw one whose start point "
        "lies inside the patient cylinder or out of the arm's reach)",
    )
    pu.add_argument("--no-report", action="store_true", help="skip the HTML report")
    ADAPTATION_DELAY_MS.add(
        pu,
        help="run the adaptation off the 1 kHz control step, its update applied MS ms after "
        "its job starts (whole control periods; default 2; 0: inline, in the sample's step)",
    )
    QP_SOLVER.add(
        pu,
        help="QP solver of the controller and the adaptation: daqp (default), quadprog "
        "(pip install 'needlekit[quadprog]') or one registered under needlekit.qp_solvers",
    )
    _flags.add_executor_options(pu)
    _flags.RESUME.add(
        pu,
        help="carry on from the DIR/puncture.partial.json an interrupted run wrote (Ctrl-C "
        "keeps the trials done): the same trials, seed and settings; only the rest run",
    )
    _flags.PLOTLY.add(pu)
    pu.set_defaults(command_handler=_cmd_puncture, sizes=_sizes.puncture_sizes)
