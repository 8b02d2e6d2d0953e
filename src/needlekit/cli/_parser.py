"""The argument parser of every ``needlekit`` command."""

from __future__ import annotations

import argparse
from pathlib import Path

from needlekit import __version__
from needlekit.cli._common import (
    _non_negative,
    _numbers,
    _Parser,
    _positive,
    _positive_int,
    _problem_overrides,
    _seed,
)
from needlekit.cli._paths import add_input, add_output
from needlekit.constants import DEFAULT_TIME_LIMIT_S

#: What ``needlekit puncture`` writes in its --out folder.
PUNCTURE_FILES = ("puncture.json", "puncture.html")
#: The papers ``needlekit reproduce`` re-runs (keys of :data:`needlekit.reproduce.PAPERS`).
REPRODUCE_PAPERS = ("feng2023", "liu2016", "tang", "lecture")
#: What ``needlekit reproduce`` writes in its --out folder (besides a folder per paper).
REPRODUCE_FILES = tuple(f"{k}.{e}" for k in REPRODUCE_PAPERS for e in ("html", "json"))
#: What ``needlekit study feng-lungs`` writes in its --out folder (as
#: ``needlekit.studies.feng_lungs.FENG_LUNGS_FILES``; a test keeps them equal).
FENG_LUNGS_FILES = (
    "goal1/scenario.yaml",
    "goal1/sweep.json",
    "goal1/plan.json",
    "goal2/scenario.yaml",
    "goal2/sweep.json",
    "goal2/plan.json",
    "feng_lungs.json",
    "report.html",
)
#: What ``needlekit demo`` writes in its --out folder.
DEMO_FILES = (
    "lung/scenario.yaml",
    "lung/sweep.json",
    "lung/plan.json",
    "lung/report.html",
    "forward_steering_planar.png",
    "forward_steering_3d.png",
    "inverse_steering.png",
    "reachability.png",
    "demo.json",
    "phantoms.html",
    "phantoms.json",
)


_EXECUTOR_FLAGS = {
    "executor": "--executor",
    "workers": "--workers",
    "dask_workers": "--dask-workers",
    "scheduler": "--scheduler",
}


def _executor_conflict(given: dict) -> str | None:
    """Why the executor flags given contradict each other, or None."""
    kind, sched, dask_n = given.get("executor"), given.get("scheduler"), given.get("dask_workers")
    if sched is not None and dask_n is not None:
        return "--scheduler uses a running Dask cluster, --dask-workers starts one: give one"
    if sched is not None and given.get("workers") is not None:
        return "--workers does not apply with --scheduler: the cluster has its own workers"
    if dask_n is not None and given.get("workers") is not None:
        return "give --dask-workers N or --workers N, not both"
    for name in ("scheduler", "dask_workers"):
        if given.get(name) is not None and kind not in (None, "dask"):
            return f"{_EXECUTOR_FLAGS[name]} runs on Dask: it contradicts --executor {kind}"
    if kind == "serial" and given.get("workers") is not None:
        return "--workers starts worker processes: it contradicts --executor serial"
    if sched is not None and (not sched.strip() or any(c.isspace() for c in sched)):
        return f"--scheduler: expected an address such as tcp://HOST:PORT, got {sched!r}"
    return None


class _ExecutorChoice(argparse.Action):
    """``--executor``, ``--workers``, ``--dask-workers`` and ``--scheduler`` read as one
    choice, in any order: ``--scheduler`` and ``--dask-workers`` mean Dask, ``--workers``
    alone a process pool; a contradiction is an error before any work."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = {**(getattr(namespace, "executor_flags", None) or {}), self.dest: values}
        problem = _executor_conflict(given)
        if problem:
            parser.error(problem)
        namespace.executor_flags = given
        dask = given.get("scheduler") is not None or given.get("dask_workers") is not None
        implied = "dask" if dask else "process" if given.get("workers") else "serial"
        namespace.executor = given.get("executor") or implied
        namespace.workers = given.get("workers") or given.get("dask_workers")
        namespace.dask_workers = given.get("dask_workers")
        namespace.scheduler = given.get("scheduler")


def _executor_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--executor",
        choices=["serial", "process", "dask"],
        default="serial",
        action=_ExecutorChoice,
        help="where tasks run: this process, a local process pool, or Dask (default serial; "
        "process with --workers alone; dask with --dask-workers or --scheduler)",
    )
    p.add_argument(
        "--workers",
        type=_positive_int,
        action=_ExecutorChoice,
        help="worker processes of the pool or local Dask cluster (default: one per CPU); "
        "alone, a process pool",
    )
    p.add_argument(
        "--dask-workers",
        type=_positive_int,
        metavar="N",
        action=_ExecutorChoice,
        help="start a local Dask cluster of N worker processes (--executor dask --workers N)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        action=_ExecutorChoice,
        help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://HOST:PORT; "
        "implies --executor dask); its workers need needlekit and the data at the same paths",
    )


def _rrt_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--rrt-connection",
        choices=["arc_line", "arc"],
        help="RRT's greedy goal connection: arc then line (default) or one arc to the target "
        "(the reference implementation's rule, behind Feng et al.'s tables)",
    )


def _dynamic_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--dynamic",
        action="store_true",
        help="among the scenario's moving obstacles: advance --step-mm along each plan, then "
        "plan again from the tip; also the plan made once at t = 0, executed open-loop",
    )
    p.add_argument(
        "--insertion-speed-mm-s",
        type=_positive,
        help="with --dynamic: insertion speed (default: the scenario's dynamic block)",
    )
    p.add_argument(
        "--step-mm",
        type=_positive,
        help="with --dynamic: advance between re-plans (default: the scenario's, else 5 mm)",
    )
    p.add_argument(
        "--predict",
        choices=["arrival", "swept", "snapshot"],
        help="with --dynamic: plan against each moving obstacle wherever it may be when the "
        "tip passes (default), swept over the next advance, or where it is now",
    )
    p.add_argument(
        "--lookahead-s",
        type=_non_negative,
        help="with --predict swept: how long to sweep (default: the advance's time)",
    )


def _cache_options(p: argparse.ArgumentParser) -> None:
    from pathlib import Path

    p.add_argument(
        "--cache-dir",
        type=Path,
        metavar="DIR",
        help="prepared-anatomy cache of Med-RAD patients (default $NEEDLEKIT_CACHE_DIR, "
        "else $XDG_CACHE_HOME/needlekit or ~/.cache/needlekit)",
    )
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="prepare the anatomy in memory only: neither read nor write the cache",
    )


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="needlekit",
        description="Planning and executing robot-assisted needle insertions.",
        epilog="Units: mm, rad (degrees where an option says _deg), s. World frame: RAS.",
    )
    parser.add_argument("--version", action="version", version=f"needlekit {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    kin = sub.add_parser(
        "kinematics", help="bevel-tip needle kinematics: forward and inverse steering"
    )
    kin_sub = kin.add_subparsers(dest="kin_command", metavar="MODE", parser_class=_Parser)

    fwd = kin_sub.add_parser(
        "forward",
        help="tip trajectory of the 3D bevel-tip model for piecewise-constant inputs",
        description=(
            "Forward steering: propagate the tip pose exactly for segments of constant "
            "insertion speed u1 (mm/s) and spin rate u2 (rad/s)."
        ),
    )
    fwd.add_argument(
        "--kappa-per-mm", type=_non_negative, required=True, help="needle curvature (1/mm)"
    )
    fwd.add_argument(
        "--segment",
        type=_numbers(3, "three numbers u1_mm_s,u2_rad_s,duration_s"),
        action="append",
        required=True,
        metavar="U1,U2,T",
        help="one input segment; repeat for several",
    )
    add_input(fwd, "--start-pose", help="4x4 start pose text file (RAS mm); default identity")
    fwd.add_argument(
        "--dt-s", type=_positive, default=None, help="sampling interval of the printed trajectory"
    )
    fwd.add_argument("--json", action="store_true", help="print JSON instead of a table")

    inv = kin_sub.add_parser(
        "inverse",
        help="single-arc inverse steering from a tip pose to target points",
        description=(
            "Inverse steering with the transformation-matrix method: the arc (alpha, r, "
            "phi, l) from the tip through each target, and the shortest arc-then-line path "
            "when --r-min-mm is given."
        ),
    )
    inv.add_argument(
        "--target",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        action="append",
        required=True,
        metavar="X,Y,Z",
        help="target point in the world frame (mm); repeat for several",
    )
    add_input(inv, "--start-pose", help="4x4 start pose text file (RAS mm); default identity")
    inv.add_argument(
        "--r-min-mm", type=_positive, help="minimum radius of curvature; tighter arcs are an error"
    )
    inv.add_argument("--json", action="store_true", help="print JSON instead of a table")

    sub.add_parser(
        "schema",
        help="print the JSON Schema of scenario files",
        description="Print the JSON Schema (draft 2020-12) that scenario files are validated against.",
    )

    scene = sub.add_parser("scene", help="inspect and render the anatomy of a scenario")
    scene_sub = scene.add_subparsers(dest="scene_command", metavar="ACTION", parser_class=_Parser)
    info = scene_sub.add_parser(
        "info", help="summarise the structures: role, extent, voxel size, volume"
    )
    add_input(info, "scenario", help="scenario file (YAML)")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    render = scene_sub.add_parser(
        "render", help="write a self-contained interactive 3D view (HTML)"
    )
    add_input(render, "scenario", help="scenario file (YAML)")
    add_output(render, "--out", required=True, help="output HTML file")
    render.add_argument(
        "--max-cells",
        type=_positive_int,
        default=160,
        help="surface resolution: samples per axis (default 160)",
    )

    planp = sub.add_parser(
        "plan",
        help="plan a curved (steerable) needle path for a scenario",
        description="Plan with RCS*, RCS or RRT and write plan.json; exit 0 with a plan, 1 without.",
    )
    add_input(planp, "scenario", help="scenario file (YAML)")
    _problem_overrides(planp)
    _cache_options(planp)
    planp.add_argument(
        "--planner",
        metavar="NAME",
        help="a registered planner: rcs_star, rcs, rrt or one a plug-in registers "
        "(default: the scenario's, else rcs_star)",
    )
    add_output(planp, "--out", default="plan.json", help="plan file to write (default plan.json)")
    planp.add_argument(
        "--goals",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        nargs="+",
        metavar="X,Y,Z",
        help="several targets (RAS mm): a plan to each, written together to --out",
    )
    planp.add_argument(
        "--multi",
        choices=["per-target", "one-tree"],
        default="per-target",
        help="with --goals: a new search from the start for each target, as the lecture "
        "does (default), or one RRT tree for all of them (rrt only)",
    )
    add_output(
        planp,
        "--report",
        help="with --goals or --dynamic: a self-contained HTML view of the plans",
    )
    planp.add_argument(
        "--time-limit-s", type=_positive, help="planning budget (default: the scenario's, else 1 s)"
    )
    planp.add_argument(
        "--seed", type=_seed, help="seed of randomised planners (default: the scenario's, else 0)"
    )
    planp.add_argument(
        "--max-iterations",
        type=_positive_int,
        help="iteration budget besides the time limit (reproducible runs; default: the scenario's)",
    )
    _rrt_option(planp)
    _dynamic_options(planp)

    sw = sub.add_parser(
        "sweep",
        help="plan over the start directions of the effective puncture region (Feng et al.)",
        description="Sample start directions around the scenario's start point, keep those at least "
        "min_puncture_angle_deg from the entry surface, plan from each, and write sweep.json.",
    )
    add_input(sw, "scenario", help="scenario file (YAML)")
    _problem_overrides(sw)
    _cache_options(sw)
    sw.add_argument(
        "--planner",
        nargs="+",
        metavar="NAME",
        help="registered planner(s) to compare (default: the scenario's, else rcs_star)",
    )
    add_output(sw, "--out", default="sweep.json", help="sweep table to write (default sweep.json)")
    add_output(sw, "--plan", help="also write the first planner's best plan here")
    add_output(sw, "--report", help="also write a self-contained HTML report (Fig. 8, Fig. 9)")
    sw.add_argument(
        "--directions",
        type=_positive_int,
        default=544,
        help="candidate directions on the sphere (default 544)",
    )
    sw.add_argument(
        "--time-limit-s",
        type=_positive,
        help="budget per direction (default: the scenario's, else 1 s as Feng et al.)",
    )
    sw.add_argument(
        "--seed", type=_seed, help="seed of randomised planners (default: the scenario's, else 0)"
    )
    sw.add_argument(
        "--healpix",
        type=_positive_int,
        metavar="NSIDE",
        help="use the 12 NSIDE^2 equal-area HEALPix directions instead of --directions",
    )
    sw.add_argument(
        "--max-iterations",
        type=_positive_int,
        help="iteration budget per direction besides the time limit (reproducible sweeps; "
        "default: the scenario's)",
    )
    _executor_options(sw)
    _rrt_option(sw)

    ver = sub.add_parser(
        "verify",
        help="re-check a plan file independently; exit 1 on any violation",
        description="Check clearance, curvature, length, heading, entry angle and goal tolerance of a plan.",
    )
    add_input(ver, "scenario", help="scenario file (YAML)")
    add_input(ver, "plan", help="plan file (plan.json)")
    _problem_overrides(ver)
    _cache_options(ver)
    ver.add_argument("--json", action="store_true", help="print JSON instead of text")

    cf = sub.add_parser(
        "cfrw",
        help="the collision-free reachable workspace of a straight needle (Liu et al. 2016)",
        description="Map every direction to one target of the scenario's straight block: entry, "
        "length, certified clearance, blocking reason; boundary layers; best entries; Pareto front.",
    )
    add_input(cf, "scenario", help="scenario file with a straight block (YAML)")
    add_output(cf, "--out", default="cfrw.json", help="map to write (default cfrw.json)")
    cf.add_argument("--target", type=_positive_int, default=1, help="which target (default 1)")
    cf.add_argument(
        "--resolution-deg", type=_positive, help="grid step (default: the scenario's, else 1)"
    )
    cf.add_argument(
        "--layers",
        type=_positive,
        nargs="+",
        default=[150.0, 160.0, 170.0],
        metavar="H_MM",
        help="heights of the boundary layers above the target (default 150 160 170, Fig. 11)",
    )
    _cache_options(cf)

    mu = sub.add_parser(
        "multi",
        help="plan several straight needles one after another (Liu et al. 2016, Fig. 4)",
        description="CFRW per needle, the optimal entry in it, placed needles as obstacles, "
        "targets moved by the deformation; write multi.json; exit 0 when every needle is planned.",
    )
    add_input(mu, "scenario", help="scenario file with a straight block (YAML)")
    add_output(mu, "--out", default="multi.json", help="plan to write (default multi.json)")
    add_output(
        mu, "--markups", folder=True, help="also write each trajectory as a Slicer line (.mrk.json)"
    )
    add_output(
        mu, "--report", help="also write a self-contained HTML report (Fig. 11/14/17, scene)"
    )
    mu.add_argument(
        "--planner", default="liu_cfrw", metavar="NAME", help="straight planner (default liu_cfrw)"
    )
    mu.add_argument(
        "--resolution-deg", type=_positive, help="CFRW grid step (default: the scenario's, else 1)"
    )
    mu.add_argument(
        "--objective",
        choices=["min_length", "max_clearance", "min_normal_angle"],
        help="what each trajectory optimises (default: the scenario's, else min_length)",
    )
    mu.add_argument(
        "--order",
        type=_positive_int,
        nargs="+",
        metavar="K",
        help="fixed insertion order (1-based targets)",
    )
    mu.add_argument(
        "--time-limit-s", type=_positive, default=3600.0, help="budget (default 3600 s)"
    )
    _cache_options(mu)

    ap = sub.add_parser(
        "approach",
        help="which skin triangles a straight needle can come from (Slicer's "
        "PercutaneousApproachAnalysis, exactly, and with needlekit's criteria)",
        description="For one target, every triangle of the entry surface's mesh: the line to "
        "the target against the obstacles' meshes (PAA's test, exact), and the needle's "
        "certified clearance, inside-the-body, length and angle limits (needlekit's); the "
        "accessible area fractions and shortest lines. Exit 1 when no triangle is accessible.",
    )
    add_input(ap, "scenario", help="scenario file with a straight block (YAML)")
    add_output(ap, "--out", default="approach.json", help="analysis (default approach.json)")
    add_output(ap, "--report", help="also write a self-contained HTML view of the skin map")
    ap.add_argument("--target", type=_positive_int, default=1, help="which target (default 1)")
    ap.add_argument(
        "--max-cells",
        type=_positive_int,
        default=200,
        help="marching-cubes samples per axis for structures without a mesh file (default 200)",
    )
    ap.add_argument("--summary-only", action="store_true", help="leave the per-triangle arrays out")
    _cache_options(ap)

    mk = sub.add_parser(
        "markups",
        help="export a plan's tip path as a 3D Slicer Markups curve (.mrk.json, LPS)",
        description="Write the tip path of plan.json as a Slicer Markups Curve: control points "
        "at most --spacing-mm apart along the path, in LPS mm. Open it in Slicer with "
        "File > Add Data.",
    )
    add_input(mk, "plan", help="plan file (plan.json, as `needlekit plan` writes it)")
    add_output(mk, "--out", required=True, help="markups file to write (.mrk.json)")
    mk.add_argument(
        "--spacing-mm",
        type=_positive,
        help="largest spacing of the curve's control points along the path (default 2 mm)",
    )

    pu = sub.add_parser(
        "puncture",
        help="simulate robotic punctures with adaptive VFI control (Tang et al., Section III)",
        description="Run simulated punctures of a Panda guided by EM sensors under kinematic "
        "uncertainty and write DIR/puncture.json and DIR/puncture.html.",
    )
    pu.add_argument("--trials", type=_positive_int, default=100, help="trials (default 100)")
    pu.add_argument("--seed", type=_seed, default=0, help="root seed (default 0)")
    add_output(
        pu,
        "--out",
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
        type=_non_negative,
        default=1.5,
        help="ball in which the adaptation may grow the task error (0: the paper's row; "
        "default 1.5)",
    )
    pu.add_argument(
        "--history",
        type=int,
        default=40,
        metavar="KEYFRAMES",
        help="measurement keyframes in the adaptation objective (0: the newest alone; default 40)",
    )
    pu.add_argument(
        "--guide-samples",
        type=int,
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
    from needlekit.cli.puncture import adaptation_delay_ms  # light: no numpy

    pu.add_argument(
        "--adaptation-delay-ms",
        type=adaptation_delay_ms,
        default=0.0,
        metavar="MS",
        help="run the adaptation off the 1 kHz control step, its update applied MS ms after "
        "its job starts (whole control periods; default 0: inline, in the sample's step)",
    )
    _executor_options(pu)

    rp = sub.add_parser(
        "report",
        help="draw result files (plan, sweep, cfrw, multi, puncture, dynamic) on one self-contained page",
        description="Read result files written by plan, plan --goals, plan --dynamic, sweep, cfrw, multi and "
        "puncture, load the scenarios they name, check their plans again and write one HTML "
        "page (opens offline) with a part per result: 3D scenes, tables, figures. Exit 1 "
        "when an independent check fails (the page is written).",
    )
    rp.add_argument("results", type=Path, nargs="+", metavar="RESULT", help="result files (JSON)")
    add_output(rp, "--out", required=True, help="HTML page to write")
    rp.add_argument(
        "--scenario",
        type=Path,
        action="append",
        metavar="FILE",
        help="the scenario, where the one a result names has moved: once for every result "
        "that reads one, or repeated, once per such result in order",
    )
    rp.add_argument("--title", help="page title (default: from the results)")
    _cache_options(rp)

    demo = sub.add_parser("demo", help="run the main demonstration job and write its outputs")
    add_output(
        demo,
        "--out",
        folder=True,
        contents=DEMO_FILES,
        default="out/demo",
        help="output folder (default out/demo)",
    )

    rq = sub.add_parser(
        "reproduce",
        help="re-run a source paper's experiments; one page beside the paper's numbers",
        description="Re-run the experiments of one or more source papers (feng2023: Feng et "
        "al. 2023; liu2016: Liu et al. 2016; tang: Tang et al.; lecture: the needle path "
        "planning lecture) and write, per paper, PAPER.html (needlekit's figures and numbers "
        "beside the paper's, the setup side by side, the deviations listed, the duration), "
        "PAPER.json and the results in PAPER/. --quick runs a reduced version in under 2 "
        "minutes per paper on 2 cores. Exit 1 when a planned path fails its independent check.",
    )
    rq.add_argument(
        "papers",
        nargs="+",
        choices=[*REPRODUCE_PAPERS, "all"],
        metavar="PAPER",
        help=f"one or more of {', '.join(REPRODUCE_PAPERS)}, or all",
    )
    add_output(
        rq,
        "--out",
        folder=True,
        contents=REPRODUCE_FILES,
        default="out/reproduce",
        help="output folder (default out/reproduce)",
    )
    rq.add_argument(
        "--quick", action="store_true", help="the reduced version (under 2 minutes per paper)"
    )
    _executor_options(rq)

    study = sub.add_parser("study", help="studies over many real cases, one table each")
    study_sub = study.add_subparsers(dest="study_command", metavar="STUDY", parser_class=_Parser)
    sl = study_sub.add_parser(
        "livers",
        help="every Med-RAD liver nodule ablated by straight needles (issue 11)",
        description="For each Med-RAD liver, each start pose and its nodule, and each gamma: "
        "targets chosen to cover the nodule plus margin, trajectories planned as `needlekit "
        "multi` plans examples/medrad_liver4.yaml, every planned needle re-checked; what "
        "blocks a case that is not covered is said.",
    )
    add_output(sl, "--out", default="livers.json", help="study record (default livers.json)")
    sl.add_argument("--livers", type=_positive_int, nargs="+", help="patients (default every one)")
    sl.add_argument(
        "--gamma",
        type=_non_negative,
        nargs="+",
        default=[1.5, 3.0],
        metavar="MM",
        help="safety distances (default 1.5 3)",
    )
    sl.add_argument("--resolution-deg", type=_positive, help="CFRW grid step (default 1)")
    add_input(
        sl,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    _cache_options(sl)

    # -- study feng-lungs (issue 12, point 1) --
    sf = study_sub.add_parser(
        "feng-lungs",
        help="Feng et al.'s effective-region protocol on a Med-RAD lung, two targets (issue 12)",
        description="Feng et al.'s protocol on real anatomy: Med-RAD lung 5 from start 1's "
        "point, their needle (2 mm, r_min 50 mm, l_max 100 mm, alpha 20 deg, tau 1 mm), 544 "
        "start directions, RCS*, RCS and RRT 1 s each, to the given target and a second one "
        "(Feng's goal offset). Writes per target the scenario, sweep.json and the best RCS* "
        "plan, feng_lungs.json (Table 4 beside Feng's) and report.html. Exit 1 when a plan "
        "fails its independent check or no planner reaches a target.",
    )
    add_output(
        sf,
        "--out",
        folder=True,
        contents=FENG_LUNGS_FILES,
        required=True,
        help="output folder",
    )
    sf.add_argument(
        "--time-limit-s", type=_positive, help="budget per direction and planner (default 1)"
    )
    sf.add_argument(
        "--directions", type=_positive_int, help="candidate start directions (default 544)"
    )
    sf.add_argument(
        "--max-iterations", type=_positive_int, help="iteration budget per direction (default none)"
    )
    sf.add_argument("--seed", type=_seed, default=0, help="seed of RRT (default 0)")
    sf.add_argument(
        "--quick",
        action="store_true",
        help="136 directions, 300 iterations per direction (a minute or so; flags given win)",
    )
    sf.add_argument(
        "--rrt-connection",
        choices=["arc", "arc_line"],
        default="arc",
        help="RRT's goal connection: one arc to the target (default, the reference "
        "implementation's rule behind Feng's tables) or arc then line",
    )
    add_input(
        sf,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    _cache_options(sf)
    _executor_options(sf)

    bench = sub.add_parser(
        "bench", help="benchmarks that record machine, versions, inputs and figures"
    )
    bench_sub = bench.add_subparsers(dest="bench_command", metavar="SUITE", parser_class=_Parser)
    bk = bench_sub.add_parser("kinematics", help="arcs propagated and sampled per second")
    add_output(bk, "--out", help="write the record as JSON here")
    bk.add_argument("--arcs", type=_positive_int, default=200_000, help="arcs per batch")
    bk.add_argument(
        "--samples", type=_positive_int, default=32, help="points per sampled arc (>= 2)"
    )
    bk.add_argument(
        "--repeat", type=_positive_int, default=5, help="timed repetitions (best is kept)"
    )
    bf = bench_sub.add_parser(
        "fields", help="distance queries per second, field build times (incl. Med-RAD)"
    )
    add_output(bf, "--out", help="write the record as JSON here")
    bf.add_argument(
        "--grid", type=_positive_int, default=256, help="edge of the cubic test grids (voxels)"
    )
    bf.add_argument(
        "--queries", type=_positive_int, default=2_000_000, help="points per timed query batch"
    )
    bf.add_argument(
        "--repeat", type=_positive_int, default=3, help="timed repetitions (best is kept)"
    )
    bf.add_argument(
        "--patients",
        type=_positive_int,
        nargs="+",
        default=[1],
        help="Med-RAD lung patients to load (default 1)",
    )
    add_input(
        bf,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    bc = bench_sub.add_parser(
        "control",
        help="time of a whole puncture-control step (kinematics, VFIs, QP, adaptation)",
    )
    add_output(bc, "--out", help="write the record as JSON here")
    bc.add_argument(
        "--trials", type=_positive_int, default=1, help="simulated punctures timed (default 1)"
    )
    bc.add_argument("--seed", type=_seed, default=0, help="study seed of the trials (default 0)")
    from needlekit.cli.puncture import adaptation_delay_ms  # (as in puncture's section)

    bc.add_argument(
        "--adaptation-delay-ms",
        type=adaptation_delay_ms,
        default=0.0,
        metavar="MS",
        help="time the adaptation as a job off the tick, applied MS ms after it starts "
        "(whole control periods; default 0: inline, in the sample's tick)",
    )
    bs = bench_sub.add_parser(
        "steerable",
        help="curved-needle planners on the Med-RAD lungs (status, cost, time per case)",
    )
    add_output(bs, "--out", help="write the record as JSON here")
    bs.add_argument(
        "--patients",
        type=_seed,
        nargs="+",
        default=[1, 2, 3, 4, 5],
        help="lung patients (default 1-5; 0 for none)",
    )
    bs.add_argument(
        "--scenario",
        type=Path,
        nargs="+",
        default=[],
        metavar="FILE",
        help="scenario files to run as further cases (with --patients 0: these only)",
    )
    bs.add_argument(
        "--radii",
        type=_positive,
        nargs="+",
        default=[50.0, 100.0],
        help="r_min values in mm (default 50 100)",
    )
    bs.add_argument(
        "--planners",
        nargs="+",
        default=["rcs_star", "rcs", "rrt"],
        metavar="NAME",
        help="registered planners (default rcs_star rcs rrt)",
    )
    bs.add_argument(
        "--time-limit-s",
        type=_positive,
        default=DEFAULT_TIME_LIMIT_S,
        help=f"budget per case and planner (default {DEFAULT_TIME_LIMIT_S:g} s)",
    )
    add_input(
        bs,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    add_input(
        bs,
        "--reference-app",
        metavar="PATH",
        help="a built rcs_star of the UNC reference planner: run it beside needlekit's "
        "rcs_star on every lung case, interleaved (its budget is its stock 1 s)",
    )
    bs.add_argument(
        "--reference-work",
        type=Path,
        metavar="DIR",
        help="folder for the reference app's case files (default: a temporary folder)",
    )
    ba = bench_sub.add_parser(
        "approach",
        help="approach analysis on Med-RAD liver 4 beside Slicer's PercutaneousApproachAnalysis "
        "(its VTK procedure, when vtk is installed)",
    )
    add_output(ba, "--out", help="write the record as JSON here")
    ba.add_argument(
        "--repeat", type=_positive_int, default=3, help="timed runs per side (median, min)"
    )
    add_input(
        ba,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    bt = bench_sub.add_parser(
        "straight",
        help="straight multi-needle planning: 1-degree CFRW map, layer, whole plan, check",
    )
    add_output(bt, "--out", help="write the record as JSON here")
    bt.add_argument(
        "--repeat", type=_positive_int, default=3, help="timed runs per stage (median, min)"
    )
    bt.add_argument(
        "--livers",
        type=_seed,
        nargs="+",
        default=[4],
        help="Med-RAD livers, each from examples/medrad_liverN.yaml (default 4; 0 for none)",
    )
    add_input(
        bt,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    bsc = bench_sub.add_parser(
        "scale",
        help="how cost grows: planning vs path length and obstacle density, sweeps vs "
        "directions and workers, the control study vs trials",
        description="Preparation of one Med-RAD lung (cold, warm); RCS* on every start of "
        "each lung against the straight distance and the obstacle density around it; Feng's "
        "goal 1 on lung 5 swept at several sizes here, on process pools and on local Dask "
        "clusters; the puncture study at several sizes. About 15 min on 2 cores (--quick: "
        "about 1 min; flags given win). `needlekit report` draws the record.",
    )
    add_output(bsc, "--out", help="write the record as JSON here")
    bsc.add_argument(
        "--quick",
        action="store_true",
        help="lung 1, 34 and 68 directions, 1 and 2 trials in this process",
    )
    bsc.add_argument(
        "--patients", type=_seed, nargs="+", help="Med-RAD lungs (default 1-5; 0 for none)"
    )
    bsc.add_argument(
        "--planners",
        nargs="+",
        metavar="NAME",
        help="registered planners of the planning series (default rcs_star)",
    )
    bsc.add_argument(
        "--directions",
        type=_seed,
        nargs="+",
        help="sweep sizes (default 34 68 136 272 544; 0 for no sweep)",
    )
    bsc.add_argument(
        "--workers",
        type=_positive_int,
        nargs="+",
        help="worker processes of the sweeps and the study (default 1 2; 1: this process)",
    )
    bsc.add_argument(
        "--dask-workers",
        type=_seed,
        nargs="+",
        metavar="N",
        help="local Dask clusters of the sweeps (default 4, more than the cores on a "
        "2-core machine; 0 for none)",
    )
    bsc.add_argument(
        "--trials", type=_seed, nargs="+", help="study sizes (default 1 2 5 10; 0 for none)"
    )
    bsc.add_argument(
        "--max-iterations",
        type=_positive_int,
        help="iteration budget per planner run (default 1000)",
    )
    bsc.add_argument(
        "--time-limit-s",
        type=_positive,
        help="time cap per planner run, only reached on a loaded machine (default 30)",
    )
    add_input(
        bsc,
        "--medrad",
        folder=True,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    return parser
