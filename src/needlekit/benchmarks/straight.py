"""``needlekit bench straight``: the straight multi-needle planner's speed.

Targets: a CFRW map at 1 degree for one target in at most 1 s; a whole
multi-needle plan (order, every trajectory) in at most 10 s, the prepared anatomy
excluded and reported apart.

Cases: the built-in liver phantom through ``examples/liver_phantom_multi.yaml`` (three
needles, gamma 1.5 mm), and Med-RAD livers through ``examples/medrad_liverN.yaml`` when
both the data and the file are there (otherwise the case is recorded as skipped, saying
why). Each case is built by :func:`needlekit.scenario.straight.multi_problem_from_scenario` on
the file, as ``needlekit multi`` builds it, and each stage is timed on its own with
``time.perf_counter`` over ``repeat`` runs (median and min):

- ``prepare``: loading the scenario and building every field the plan reads (excluded
  from the targets);
- ``cfrw_map``: :func:`~needlekit.planning.straight.cfrw.cfrw_map` for the first target
  (after one untimed warm-up call, whose time is ``first_call_s``: numba kernels load),
  with its grid and free/blocked counts; beside it, where its time goes:
  :func:`~needlekit.planning.straight.cfrw.entry_points` and
  :func:`~needlekit.planning.straight.cfrw.segment_clearance_bound` timed alone on the
  map's own directions, the entry surface's gradient, and the rest;
- ``layer``: :meth:`CFRWMap.layer` at ``h`` (150 mm), apart;
- ``multi_plan``: ``liu_cfrw`` from the registry on the whole problem (order search, every
  needle's map with the placed needles, every trajectory), at the benchmark's resolution;
  once more at the scenario's own resolution for the fixed outcome the example documents;
- ``verify``: :func:`~needlekit.planning.straight.verify.verify_multi` on the plan's
  record.

When a target is not met, the record holds a cProfile of that stage (top functions by
own time). Speed is reported, never asserted: the ``met`` flags are the median against
the target.
"""

from __future__ import annotations

import contextlib
import cProfile
import os
import pstats
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.medrad_paths import patient_folder
from needlekit.planning.interface import Termination, get_planner
from needlekit.provenance import machine_info
from needlekit.scenario.straight import coverage_region, multi_problem_from_scenario

__all__ = ["TARGETS_S", "run_straight_benchmark"]

#: The straight planner's speed targets (s): one 1-degree CFRW map, one whole multi-needle plan.
TARGETS_S: dict[str, float] = {"cfrw_map_1deg_s": 1.0, "multi_plan_s": 10.0}
#: Sigma height (mm) of the layer timed (the paper's Fig. 11 plane).
LAYER_H_MM: float = 150.0
#: Budget of each whole plan (s): far above the target, so the time is the plan's own.
PLAN_TIME_LIMIT_S: float = 3600.0
#: Functions kept from a profile of a stage that misses its target.
PROFILE_TOP: int = 12

PHANTOM_SCENARIO = "liver_phantom_multi.yaml"


def _examples_dir() -> Path:
    # src/needlekit/benchmarks/straight.py -> the repository root is parents[3]
    here = Path(__file__).resolve()
    for root in (here.parents[3], Path.cwd()):
        if (root / "examples" / PHANTOM_SCENARIO).is_file():
            return root / "examples"
    return here.parents[3] / "examples"


def _numba_threads() -> int:
    # the phantom's and voxel fields' kernels run in parallel on this many threads: a busy
    # core slows every parallel call down to its slowest thread
    import numba

    return int(numba.get_num_threads())


def _timed(fn: Callable[[], Any], repeat: int) -> tuple[dict, Any]:
    """Run ``fn`` ``repeat`` times: (``median_s``, ``min_s``, ``runs_s``), last result."""
    runs, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        runs.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(runs), "min_s": min(runs), "runs_s": runs}, out


def _profile(fn: Callable[[], Any], top: int = PROFILE_TOP) -> list[dict]:
    """One profiled call of ``fn``: the ``top`` functions by own time."""
    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    st = pstats.Stats(prof)
    rows = []
    for (file, line, name), (_, ncalls, tottime, cumtime, _) in st.stats.items():
        where = Path(file).name if file != "~" else ""
        rows.append(
            {
                "function": f"{where}:{line}({name})" if where else name,
                "calls": int(ncalls),
                "own_s": float(tottime),
                "cumulative_s": float(cumtime),
            }
        )
    rows.sort(key=lambda r: -r["own_s"])
    return rows[:top]


@contextlib.contextmanager
def _medrad_env(medrad_dir):
    """Scenario files find Med-RAD through ``$NEEDLEKIT_MEDRAD``: point it at ``medrad_dir``
    while they load."""
    from needlekit.io.medrad import MEDRAD_ENV

    if medrad_dir is None:
        yield
        return
    saved = os.environ.get(MEDRAD_ENV)
    os.environ[MEDRAD_ENV] = str(medrad_dir)
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(MEDRAD_ENV, None)
        else:
            os.environ[MEDRAD_ENV] = saved


def _prepare(path: Path, medrad_dir):
    """Load the scenario as ``needlekit multi`` does and build every field the plan reads
    (lazy voxel fields included), so that the stages after it time planning alone."""
    from needlekit.scenario.loading import load_scenario

    with _medrad_env(medrad_dir):
        sc = load_scenario(path)
        multi, options = multi_problem_from_scenario(sc)
    problem = multi.problem
    target = multi.targets_mm[:1]
    problem.scene[problem.entry_surface].field.signed_distance(target)
    problem.obstacle_field().signed_distance(target)
    return sc, multi, dict(options)


def _uses_coverage(sc) -> bool:
    """The scenario's targets are chosen by ablation coverage (``targets: coverage``)."""
    return isinstance((sc.straight or {}).get("targets"), str)


def _map_split(m, repeat: int) -> dict:
    """Where the map's time goes: its entry search, clearance and normal angles timed alone
    on the map's own directions (the same calls :func:`cfrw_map` makes)."""
    from needlekit.planning.straight.cfrw import (
        CLEARANCE_CAP_ABOVE_GAMMA_MM,
        NEAR_STEP_MM,
        Blocked,
        entry_points,
        segment_clearance_bound,
    )

    pr = m.problem
    body = pr.scene[pr.entry_surface].field
    flat = m.directions.reshape(-1, 3)
    searched = m.blocked.reshape(-1) != Blocked.ANGLE_LIMIT
    length = m.length_mm.reshape(-1)
    has = np.isfinite(length)
    check = np.isfinite(m.clearance_mm.reshape(-1))
    entries = m.entry_mm.reshape(-1, 3)[has]
    field = pr.obstacle_field()
    cap = pr.clearance_needed_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
    origins = np.broadcast_to(pr.target_mm, (int(check.sum()), 3))
    entry_t, _ = _timed(
        lambda: entry_points(body, pr.target_mm, flat[searched], pr.needle.max_length_mm), repeat
    )
    normal_t, _ = _timed(lambda: body.gradient(entries), repeat)
    clear_t, (bound, _) = _timed(
        lambda: segment_clearance_bound(
            field, origins, flat[check], length[check], cap_mm=cap, step_mm=NEAR_STEP_MM
        ),
        repeat,
    )
    same = float(np.max(np.abs(bound - pr.needle.radius_mm - m.clearance_mm.reshape(-1)[check])))
    return {
        "entry_search": {**entry_t, "directions": int(searched.sum())},
        "normal_angle": {**normal_t, "directions": int(has.sum())},
        "clearance": {**clear_t, "directions": int(check.sum())},
        "clearance_max_abs_diff_vs_map_mm": same,
    }


def _plan(sc, multi, options: dict, resolution_deg: float):
    """The whole plan as ``needlekit multi`` makes it: (plan, coverage outcome or None,
    seconds per step).

    With ``targets: coverage``: the tumour-plus-margin region, the targets chosen, the
    trajectories planned, the coverage re-checked along them and, when those directions
    lost it, one more round of targets chosen along them and planned (as the command
    does). Otherwise the scenario's targets are planned.
    """
    planner = get_planner("liu_cfrw", {**options, "resolution_deg": resolution_deg})
    steps: dict[str, float] = {"rounds": 1}

    def step(name, fn):
        t0 = time.perf_counter()
        out = fn()
        steps[name] = steps.get(name, 0.0) + time.perf_counter() - t0
        return out

    def solve(targets):
        return step(
            "trajectories_s",
            lambda: planner.solve(
                replace(multi, targets_mm=targets), Termination(PLAN_TIME_LIMIT_S)
            ),
        )

    if not _uses_coverage(sc):
        return solve(multi.targets_mm), None, steps
    from needlekit.planning.straight.ablation import plan_coverage

    region, settings = step("coverage_region_s", lambda: coverage_region(sc, multi.problem))
    plan, outcome = plan_coverage(
        multi, planner, region, settings, time_limit_s=PLAN_TIME_LIMIT_S, timings=steps
    )
    return plan, outcome, steps


def _plan_outcome(plan, coverage, steps: dict) -> dict:
    out: dict[str, Any] = {"steps_s": steps, "coverage": None}
    if coverage is not None:
        rep = coverage.planned or coverage.chosen.report
        out["coverage"] = {
            "ok": bool(coverage.ok),
            "reason": coverage.reason,
            "coverage": float(rep.coverage),
            "needles": int(rep.needles),
        }
    if plan is None:
        return {**out, "solved": False, "reason": coverage.reason, "needles": 0,
                "needles_placed": 0, "orders_tried": 0, "order": [], "lengths_mm": [],
                "clearances_mm": []}  # fmt: skip
    return {
        **out,
        "solved": bool(plan.solved),
        "reason": plan.reason,
        "needles": len(plan.needles),
        "needles_placed": sum(n.entry is not None for n in plan.needles),
        "orders_tried": int(plan.orders_tried),
        "order": [int(i) for i in plan.order],
        "lengths_mm": [None if n.entry is None else float(n.entry.length_mm) for n in plan.needles],
        "clearances_mm": [
            None if n.entry is None else float(n.entry.clearance_mm) for n in plan.needles
        ],
    }


def _first_target(sc, multi) -> tuple[np.ndarray, str]:
    """The target of the timed map: the scenario's first, or with ``targets: coverage``
    the first target the coverage chooses (the stand-in till then may sit in a vessel)."""
    if not _uses_coverage(sc):
        return multi.targets_mm[0], "the scenario's first target"
    from needlekit.planning.straight.ablation import choose_needle_targets

    region, st = coverage_region(sc, multi.problem)
    chosen = choose_needle_targets(
        multi.problem,
        region,
        st["zone"],
        max_needles=st["max_needles"],
        coverage_goal=st["coverage_goal"],
    )
    if chosen.needles == 0:
        return multi.targets_mm[0], "the tumour's centre (coverage chose no target)"
    return chosen.targets_mm[0], "the first target the coverage chooses"


def _run_case(name: str, path: Path, *, repeat, resolution_deg, layer_h_mm, medrad_dir) -> dict:
    from needlekit.planning.straight.cfrw import cfrw_map
    from needlekit.planning.straight.verify import verify_multi

    case: dict[str, Any] = {"name": name, "scenario": str(path)}
    prep, (sc, multi, options) = _timed(lambda: _prepare(path, medrad_dir), repeat)
    # the first load builds the anatomy (phantoms are memoised in the process, Med-RAD
    # patients come from the prepared-anatomy cache when it holds them): that is the figure
    case["prepare"] = {
        **prep,
        "first_s": prep["runs_s"][0],
        "excluded": True,
        "medrad_timings_s": getattr(sc.base, "timings_s", None),
    }
    scenario_res = float(options.get("resolution_deg", resolution_deg))
    target, target_from = _first_target(sc, multi)
    problem = multi.problem.with_target(target)

    def one_map():
        return cfrw_map(problem, resolution_deg=resolution_deg)

    t0 = time.perf_counter()
    one_map()
    first = time.perf_counter() - t0
    map_t, m = _timed(one_map, repeat)
    case["cfrw_map"] = {
        **map_t,
        "first_call_s": first,
        "resolution_deg": resolution_deg,
        "target_mm": problem.target_mm.tolist(),
        "target": target_from,
        "grid": list(m.blocked.shape),
        "directions": int(m.blocked.size),
        "counts": m.counts(),
        "split": _map_split(m, repeat),
    }
    layer_t, polylines = _timed(lambda: m.layer(layer_h_mm), repeat)
    case["layer"] = {
        **layer_t,
        "h_mm": layer_h_mm,
        "polylines": len(polylines),
        "vertices": int(sum(len(p) for p in polylines)),
    }

    def whole_plan():
        return _plan(sc, multi, options, resolution_deg)

    plan_t, (plan, coverage, steps) = _timed(whole_plan, repeat)
    case["multi_plan"] = {
        **plan_t,
        "resolution_deg": resolution_deg,
        "targets": len(plan.needles) if plan is not None else 0,
        "targets_from": "coverage" if _uses_coverage(sc) else "scenario",
        **_plan_outcome(plan, coverage, steps),
    }
    if scenario_res != resolution_deg:
        t0 = time.perf_counter()
        own = _plan(sc, multi, options, scenario_res)
        case["multi_plan_scenario_resolution"] = {
            "time_s": time.perf_counter() - t0,
            "resolution_deg": scenario_res,
            **_plan_outcome(*own),
        }
    if plan is not None:
        record = plan.to_dict()
        ver_t, check = _timed(lambda: verify_multi(multi.problem, record), repeat)
        case["verify"] = {**ver_t, "ok": bool(check.ok), "violations": list(check.violations)}
    met = {
        "cfrw_map_1deg_s": (
            map_t["median_s"] <= TARGETS_S["cfrw_map_1deg_s"] if resolution_deg == 1.0 else None
        ),
        "multi_plan_s": plan_t["median_s"] <= TARGETS_S["multi_plan_s"],
    }
    case["targets_s"] = dict(TARGETS_S)
    case["met"] = met
    if met["cfrw_map_1deg_s"] is False:
        case["cfrw_map"]["profile"] = _profile(one_map)
    if not met["multi_plan_s"]:
        case["multi_plan"]["profile"] = _profile(whole_plan)
    return case


def _case_paths(livers: Sequence[int], medrad_dir, examples: Path) -> list[tuple[str, Any]]:
    """(name, scenario path or the reason it is skipped) per case."""
    from needlekit.io.medrad import medrad_root

    phantom = examples / PHANTOM_SCENARIO
    out: list[tuple[str, Any]] = [
        ("liver_phantom", phantom if phantom.is_file() else f"{phantom} not found")
    ]
    if not livers:
        return out
    try:
        medrad_root(medrad_dir)
        missing = None
    except InvalidInputError as exc:
        missing = f"Med-RAD data not found: {exc}"
    if missing is None:  # a liver the data does not have is refused before any work
        for n in livers:
            patient_folder("liver", n, medrad_dir, flag="--livers")
    for n in livers:
        path = examples / f"medrad_liver{n}.yaml"
        if missing is not None:
            out.append((f"medrad_liver{n}", missing))
        elif not path.is_file():
            out.append((f"medrad_liver{n}", f"{path} not found (no scenario for liver {n} yet)"))
        else:
            out.append((f"medrad_liver{n}", path))
    return out


def _rows(case: dict) -> list[dict]:
    """Lines of the text summary for one case."""
    name = case["name"]
    if "skipped" in case:
        return [{"name": name, "summary": f"skipped: {case['skipped']}"}]

    def t(stage):
        return f"median {stage['median_s']:6.2f} s, min {stage['min_s']:6.2f} s"

    def met(key):
        flag = case["met"][key]
        target = f"target <= {TARGETS_S[key]:g} s"
        return f"{target}: n/a" if flag is None else f"{target}: {'met' if flag else 'NOT met'}"

    mp, cm, sp = case["multi_plan"], case["cfrw_map"], case["cfrw_map"]["split"]
    c = cm["counts"]
    blocked = ", ".join(f"{k} {v}" for k, v in c.items() if k != "free" and v)
    lengths = " / ".join("-" if x is None else f"{x:.2f}" for x in mp["lengths_mm"])
    rows = [
        {
            "name": f"{name} prepare",
            "summary": f"first {case['prepare']['first_s']:6.2f} s, again {t(case['prepare'])} "
            "(excluded; memoised after the first)",
        },
        {
            "name": f"{name} cfrw map {cm['resolution_deg']:g} deg",
            "summary": f"{t(cm)}  {cm['grid'][0]} x {cm['grid'][1]} directions, "
            f"{c['free']} free ({blocked}); first call {cm['first_call_s']:.2f} s; "
            f"{met('cfrw_map_1deg_s')}",
        },
        {
            "name": "  entry / normals / clearance",
            "summary": f"median {sp['entry_search']['median_s']:.2f} / "
            f"{sp['normal_angle']['median_s']:.2f} / {sp['clearance']['median_s']:.2f} s "
            f"(same directions as the map)",
        },
        {
            "name": f"{name} layer h={case['layer']['h_mm']:g} mm",
            "summary": f"{t(case['layer'])}  {case['layer']['polylines']} polylines, "
            f"{case['layer']['vertices']} vertices",
        },
        {
            "name": f"{name} multi plan {mp['resolution_deg']:g} deg",
            "summary": f"{t(mp)}  {mp['needles_placed']}/{mp['targets']} needles "
            f"({'solved' if mp['solved'] else 'not solved'}), {mp['orders_tried']} orders, "
            f"lengths {lengths} mm; {met('multi_plan_s')}",
        },
    ]
    own = case.get("multi_plan_scenario_resolution")
    if own is not None:
        ol = " / ".join("-" if x is None else f"{x:.2f}" for x in own["lengths_mm"])
        rows.append(
            {
                "name": f"  at the scenario's {own['resolution_deg']:g} deg",
                "summary": f"{own['time_s']:6.2f} s once, {own['needles_placed']} needles, "
                f"lengths {ol} mm",
            }
        )
    if mp["coverage"] is not None:
        cov, st = mp["coverage"], mp["steps_s"]
        parts = ", ".join(
            f"{k.removesuffix('_s')} {v:.2f} s" for k, v in st.items() if k[-2:] == "_s"
        )
        rows.append(
            {
                "name": "  coverage and steps",
                "summary": f"coverage {cov['coverage']:.4f} with {cov['needles']} needles "
                f"({'ok' if cov['ok'] else cov['reason']}); last run, {st['rounds']} "
                f"round(s): {parts}",
            }
        )
    if "verify" in case:
        v = case["verify"]
        rows.append(
            {"name": f"{name} verify", "summary": f"{t(v)}  {'ok' if v['ok'] else 'VIOLATED'}"}
        )
    return rows


def run_straight_benchmark(
    *,
    repeat: int = 3,
    resolution_deg: float = 1.0,
    layer_h_mm: float = LAYER_H_MM,
    livers: Sequence[int] = (4,),
    medrad_dir: str | os.PathLike | None = None,
    examples_dir: str | os.PathLike | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Time the straight multi-needle planner stage by stage against its speed targets.

    Parameters
    ----------
    repeat : int
        Timed runs of each stage (median and min reported).
    resolution_deg : float
        CFRW grid step of the timed map and plan (the targets are for 1 degree).
    layer_h_mm : float
        Sigma height of the timed layer (mm).
    livers : sequence of int
        Med-RAD livers to run, each through ``examples/medrad_liverN.yaml`` (skipped,
        saying why, without the data or the file); empty for the phantom alone.
    medrad_dir : path-like, optional
        Med-RAD folder (default :func:`needlekit.io.medrad.medrad_root`).
    examples_dir : path-like, optional
        Folder of the scenario files (default: the repository's ``examples/``).
    progress : callable, optional
        Called with the name of each case before it runs.

    Returns
    -------
    dict
        ``benchmark`` (``"straight"``), ``machine``, ``load_average`` (1, 5, 15 min, before
        and after), ``inputs``, ``targets_s``, ``cases`` (per case: ``prepare``,
        ``cfrw_map`` with ``grid``, ``counts`` and ``split``, ``layer``, ``multi_plan`` with
        the outcome, ``multi_plan_scenario_resolution``, ``verify``, ``met``; or
        ``skipped`` with the reason), ``results`` (summary lines) and ``wall_s``.
    """
    if int(repeat) < 1:
        raise InvalidInputError("repeat", f"expected a whole number >= 1, got {repeat!r}")
    examples = Path(examples_dir) if examples_dir is not None else _examples_dir()
    load_before = list(os.getloadavg())
    t_all = time.perf_counter()
    cases = []
    for name, path in _case_paths(tuple(livers), medrad_dir, examples):
        if progress is not None:
            progress(name)
        if not isinstance(path, Path):
            cases.append({"name": name, "skipped": path})
            continue
        cases.append(
            _run_case(
                name,
                path,
                repeat=int(repeat),
                resolution_deg=float(resolution_deg),
                layer_h_mm=float(layer_h_mm),
                medrad_dir=medrad_dir,
            )
        )
    rows = [row for case in cases for row in _rows(case)]
    return {
        "benchmark": "straight",
        "machine": machine_info(),
        "load_average": {"before": load_before, "after": list(os.getloadavg())},
        "inputs": {
            "scenarios": [c.get("scenario") for c in cases if "scenario" in c],
            "resolution_deg": float(resolution_deg),
            "layer_h_mm": float(layer_h_mm),
            "repeat": int(repeat),
            "livers": list(livers),
            "medrad_dir": None if medrad_dir is None else str(medrad_dir),
            "plan_time_limit_s": PLAN_TIME_LIMIT_S,
            "numba_threads": _numba_threads(),
        },
        "targets_s": dict(TARGETS_S),
        "cases": cases,
        "results": rows,
        "wall_s": time.perf_counter() - t_all,
    }
