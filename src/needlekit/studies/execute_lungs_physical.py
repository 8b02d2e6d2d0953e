"""The five lungs with a needle that bends by mechanics (``needlekit study execute-lungs
--truth physical``).

The kinematic study plans each lung from start 1 for the planner's own needle (r_min 50 mm)
and sets the margin from a pilot's deviation. A needle bent by mechanics cannot turn that
tightly (a 20 degree pre-bent nitinol tip turns at about 110 mm in the ``lung`` preset,
docs/execute.md), so the physical study chooses, per lung, plans it can follow:

1. **Directions that reach.** From each of the lung's five starts, a sweep of RCS* over
   :attr:`PhysicalLungs.directions` start directions (the Med-RAD start point, the effective
   puncture region) at ``r_min_mm`` (150 mm) and no margin, each direction with an iteration
   budget (reproducible: the time limit is set far above it).
2. **The largest margin.** For each margin of :attr:`PhysicalLungs.margins_mm` (1.5, 1.0, 0.5
   and 0 mm: 1.5 mm is 3.09 times the closed loop's 0.4-0.6 mm cross-track RMS), largest
   first, and each start in order, RCS* plans again along every direction that solved with
   none; the first margin that any start keeps wins, and its cheapest plan. (A direction
   with no plan without a margin has none with one: the margin only removes paths.)
3. **The trials**, as ``needlekit execute DIR/lungN/scenario.yaml DIR/lungN/plan.json
   --any-start-direction --truth physical`` runs them: the loop's own model calibrated on
   the needle in this lung, each sensing policy on the same draws.

The goal for the closed loop (:data:`PHYSICAL_TARGETS`) is judged on the policy
:attr:`PhysicalLungs.judged` (CT checkpoints by default): mean error at most 1.0 mm, p95 at
most 2.0 mm, no obstacle crossed by any closed loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from needlekit.errors import InvalidInputError
from needlekit.execute.physical import MechanicsSettings
from needlekit.geometry.se3 import pose_from_direction
from needlekit.io.files import write_text
from needlekit.io.plans import write_plan_json
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.planning.steerable.sweep import sphere_directions, sweep
from needlekit.scenario.problems import ScenarioSource

__all__ = [
    "PHYSICAL_R_MIN_MM",
    "PHYSICAL_TARGETS",
    "PhysicalLungs",
    "choose_physical_plan",
    "physical_scenario_document",
    "physical_verdict",
    "write_physical_case",
]

#: The radius the physical study plans for (mm): above the calibrated 109 mm of the
#: default needle in the ``lung`` preset, with room for its spread.
PHYSICAL_R_MIN_MM: float = 150.0
#: The closed loop's goal with mechanics, deformation and checkpoints.
PHYSICAL_TARGETS = {"closed_mean_error_mm": 1.0, "closed_p95_error_mm": 2.0, "crossed": 0}
#: Each direction's budget in the sweeps and plans (s): far above what the iteration
#: budget takes, so that the iterations decide (reproducible).
_SEARCH_TIME_LIMIT_S: float = 60.0


def _default_needle() -> MechanicsSettings:
    return MechanicsSettings(needle="nitinol", tissue="lung", prebend_deg=20.0)


@dataclass(frozen=True)
class PhysicalLungs:
    """The physical study's needle, organ and plan choice.

    Attributes
    ----------
    mechanics : MechanicsSettings
        The needle and tissue (default: nitinol, a 20 degree pre-bent tip, ``lung``).
    boundary : str
        The lung's boundary (``"organ"``: its pleura held; ``"sliding"``).
    r_min_mm : float
        The radius the plans are made for.
    margins_mm : tuple of float
        Tried largest first.
    starts : tuple of int
        The Med-RAD starts tried, in order.
    directions : int
        Start directions per sweep.
    max_iterations : int
        RCS*'s budget per direction.
    calibration_insertions : int
        Curved insertions the loop's model is calibrated from (and half as many straight).
    judged : str
        The sensing policy the goal is judged on.
    """

    mechanics: MechanicsSettings = field(default_factory=_default_needle)
    boundary: str = "organ"
    r_min_mm: float = PHYSICAL_R_MIN_MM
    margins_mm: tuple[float, ...] = (1.5, 1.0, 0.5, 0.0)
    starts: tuple[int, ...] = (1, 2, 3, 4, 5)
    directions: int = 200
    max_iterations: int = 2000
    calibration_insertions: int = 24
    judged: str = "checkpoints"

    def __post_init__(self) -> None:
        if not isinstance(self.mechanics, MechanicsSettings):
            raise InvalidInputError("mechanics", "expected MechanicsSettings")
        if self.boundary not in ("organ", "sliding"):
            raise InvalidInputError("boundary", f"expected organ or sliding, got {self.boundary!r}")
        if not (math.isfinite(self.r_min_mm) and self.r_min_mm > 0):
            raise InvalidInputError("r_min_mm", f"expected a radius > 0, got {self.r_min_mm!r}")
        if not self.margins_mm or any(not (0 <= m < 50) for m in self.margins_mm):
            raise InvalidInputError("margins_mm", f"expected margins in [0, 50) mm, got {self.margins_mm!r}")
        if not self.starts or any(s not in (1, 2, 3, 4, 5) for s in self.starts):
            raise InvalidInputError("starts", f"expected Med-RAD starts 1-5, got {self.starts!r}")
        for name in ("directions", "max_iterations", "calibration_insertions"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 2):
                raise InvalidInputError(name, f"expected a whole number >= 2, got {v!r}")

    def record(self) -> dict:
        """JSON-ready settings (the study's record, and a resumed run's check).

        Returns
        -------
        dict
        """
        m = self.mechanics
        return {
            "mechanics": {"needle": m.needle, "tissue": m.tissue, "prebend_deg": m.prebend_deg,
                          "prebend_length_mm": m.prebend_length_mm,
                          "inhomogeneity": m.inhomogeneity, "solve_rate_hz": m.solve_rate_hz},
            "boundary": self.boundary, "r_min_mm": self.r_min_mm,
            "margins_mm": list(self.margins_mm), "starts": list(self.starts),
            "directions": self.directions, "max_iterations": self.max_iterations,
            "calibration_insertions": self.calibration_insertions, "judged": self.judged,
            "targets": PHYSICAL_TARGETS,
        }  # fmt: skip


def physical_scenario_document(patient: int, start: int, margin_mm: float, r_min_mm: float,
                               medrad_dir=None) -> dict:  # fmt: skip
    """Med-RAD lung ``patient`` from start ``start`` for a needle of radius ``r_min_mm``: the
    reference planner's needle and exact voxel-centre test, as ``examples/medrad_lung1.yaml``
    has them for patient 1, with a clearance margin.

    Parameters
    ----------
    patient, start : int
    margin_mm, r_min_mm : float
    medrad_dir : path-like, optional

    Returns
    -------
    dict
        A scenario document.
    """
    medrad = {"organ": "lung", "patient": int(patient)}
    if medrad_dir is not None:
        medrad["root"] = str(Path(medrad_dir).expanduser().resolve())
    return {
        "version": 1,
        "name": f"Med-RAD lung {patient}, start {start}",
        "base": {"medrad": medrad},
        "needle": {
            "diameter_mm": 1.0,
            "r_min_mm": float(r_min_mm),
            "max_length_mm": 150,
            "max_heading_change_deg": 90,
            "start_exclusion_mm": 3,
            "safety_margin_mm": float(margin_mm),
        },
        "start": {"case_start": f"start{int(start)}"},
        "goal": {"case_target": "target", "tolerance_mm": 1.0},
        "collision_model": "voxel_centres",
        "planner": {"name": "rcs_star", "time_limit_s": 1.0},
    }


def _source(patient, start, margin, phys, medrad_dir):
    doc = physical_scenario_document(patient, start, margin, phys.r_min_mm, medrad_dir)
    return doc, ScenarioSource.of_document(doc, ".", name=f"lung{patient}s{start}.yaml")


def choose_physical_plan(patient: int, phys: PhysicalLungs, *, executor=None, medrad_dir=None,
                         say=None) -> tuple[dict, object, object]:  # fmt: skip
    """Steps 1 and 2 of the module notes for one lung.

    Parameters
    ----------
    patient : int
    phys : PhysicalLungs
    executor : concurrent.futures.Executor, optional
        Runs the sweeps' directions.
    medrad_dir : path-like, optional
    say : callable, optional
        Called with one line per start swept and with the choice.

    Returns
    -------
    (dict, dict or None, PlanResult or None)
        What was decided (``status`` ``"planned"`` with ``start``, ``margin_mm``,
        ``solved_directions`` per start; or why not), the scenario document and the plan.
    """
    dirs = sphere_directions(phys.directions)
    reach: dict[int, list[np.ndarray]] = {}
    for start in phys.starts:
        _, source = _source(patient, start, 0.0, phys, medrad_dir)
        _, problem = source.cached()
        swept = sweep(problem, "rcs_star", directions=dirs, executor=executor, source=source,
                      time_limit_s=_SEARCH_TIME_LIMIT_S, max_iterations=phys.max_iterations)  # fmt: skip
        reach[start] = [swept.directions[i] for i, r in enumerate(swept.results)
                        if r is not None and r.status.value == "solved"]  # fmt: skip
        if say is not None:
            say(f"lung {patient}, start {start}: {len(reach[start])} of {phys.directions} "
                f"directions reach the target at r_min {phys.r_min_mm:g} mm")  # fmt: skip
    counts = {str(s): len(v) for s, v in reach.items()}
    for margin in phys.margins_mm:
        for start in phys.starts:
            if not reach[start]:
                continue
            doc, source = _source(patient, start, margin, phys, medrad_dir)
            _, problem = source.cached()
            best = None
            for d in reach[start]:
                pose = pose_from_direction(problem.start_pose[:3, 3], d)
                res = solve_rcs(problem.with_start_pose(pose), time_limit_s=_SEARCH_TIME_LIMIT_S,
                                max_iterations=phys.max_iterations)  # fmt: skip
                if res.status.value == "solved" and (best is None or res.cost_mm < best.cost_mm):
                    best = res
            if best is not None:
                if say is not None:
                    say(f"lung {patient}: start {start} with a {margin:g} mm margin, plan "
                        f"{best.cost_mm:.1f} mm")  # fmt: skip
                decided = {"patient": patient, "status": "planned", "start": start,
                           "margin_mm": float(margin), "r_min_mm": phys.r_min_mm,
                           "solved_directions": counts, "plan_cost_mm": float(best.cost_mm)}  # fmt: skip
                return decided, doc, best
    reason = f"no start reaches the target at r_min {phys.r_min_mm:g} mm with any margin tried"
    return {"patient": patient, "status": "infeasible", "reason": reason,
            "solved_directions": counts}, None, None  # fmt: skip


def write_physical_case(case_dir, decided: dict, doc: dict, res) -> dict:
    """Write ``scenario.yaml`` and ``plan.json`` of a planned lung; ``decided`` with the
    plan's start pose and primitives (a resumed run rebuilds the plan from them).

    Parameters
    ----------
    case_dir : Path
    decided : dict
    doc : dict
    res : PlanResult

    Returns
    -------
    dict
    """
    head = (f"# Med-RAD lung {decided['patient']} (CC BY-NC-SA 4.0), written by needlekit study "
            "execute-lungs --truth physical; its plan's start direction is a sweep's "
            "(execute it with --any-start-direction)\n")  # fmt: skip
    write_text(case_dir / "scenario.yaml", head + yaml.safe_dump(doc, sort_keys=False))
    write_plan_json(case_dir / "plan.json", res, scenario="scenario.yaml")
    return {**decided, "plan_start_pose": res.plan.start_pose.tolist(),
            "plan_primitives": res.plan.primitives.tolist()}  # fmt: skip


def physical_verdict(summary: dict, judged: str) -> dict:
    """The goal (:data:`PHYSICAL_TARGETS`) on one lung's ``execute.json`` summary.

    Parameters
    ----------
    summary : dict
    judged : str
        The sensing policy judged (its closed loop).

    Returns
    -------
    dict
        Per target, whether it holds; ``crossed`` over every closed loop run.
    """
    runs = summary.get("sensing") or {"em": summary["closed_loop"]}
    e = runs[judged]["final_error_mm"] if judged in runs else {}
    crossed = sum(r["violated"] for r in runs.values())
    return {
        "closed_mean_error_mm": e.get("mean", math.inf) <= PHYSICAL_TARGETS["closed_mean_error_mm"],
        "closed_p95_error_mm": e.get("p95", math.inf) <= PHYSICAL_TARGETS["closed_p95_error_mm"],
        "crossed": crossed == 0 and not summary["crashed"],
    }
