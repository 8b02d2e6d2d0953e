"""The puncture study's guide-line filter: which random guide lines it redraws, how often
the filter refuses one, and what happens to the trials that keep a refused line.

Tang et al. (Section III-A) draw each simulated guide line ``l_g`` from random x-y-z
components in one of the four octants above the horizontal plane, with the start point
300 mm out along it. The paper describes no filter. In needlekit's simulated setup some of
those lines cannot be used, and the study draws again (``PunctureScenario.redraw_guides``)
while the filter refuses the line for one of these reasons, checked in this order (a
refused line gets the first that holds):

1. ``inside_patient_cylinder``: the start point lies within ``R_p`` (200 mm) of the
   patient cylinder's axis (world y through the target), where the arm may not go before
   the puncture;
2. ``wrist_too_close``: with the tip at the start point and the needle along ``l_g``, the
   arm's wrist (flange) lies closer than ``min_wrist_reach_mm`` to its shoulder, so the
   arm would have to fold onto itself;
3. ``wrist_too_far``: the wrist lies farther than ``max_wrist_reach_mm`` from the
   shoulder, beyond the arm's comfortable reach.

The checks use the real arm (the nominal base and needle): the filter stands for a setup
in which the patient lies where the robot can work.

The start point is ``target + d l_g`` and the cylinder's axis passes through the target,
so the first check depends on ``l_g`` alone (:func:`cylinder_refusal_share`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.records import trial_solved

__all__ = [
    "ACCEPTABLE",
    "FILTER_DRAWS_PER_OCTANT",
    "FILTER_RULE",
    "OCTANT_NAMES",
    "OCTANT_SIGNS",
    "REFUSAL_REASONS",
    "GuideFilter",
    "cylinder_refusal_share",
    "redraw_filter_rates",
    "redraw_summary",
]

#: Why the filter refuses a guide line, in the order the checks are made.
REFUSAL_REASONS = ("inside_patient_cylinder", "wrist_too_close", "wrist_too_far")
#: The verdict on a line the filter accepts.
ACCEPTABLE = "acceptable"
#: x and y signs of the four octants above the horizontal plane (trial i takes i mod 4).
OCTANT_SIGNS = ((1, 1), (-1, 1), (-1, -1), (1, -1))
OCTANT_NAMES = ("+x +y", "-x +y", "-x -y", "+x -y")
#: Guide lines drawn per octant when the study measures the filter on its own: enough
#: for a refusal rate within about 1 percentage point (binomial SD <= 0.5 %).
FILTER_DRAWS_PER_OCTANT = 10_000
#: The filter in one sentence (for the JSON and the page).
FILTER_RULE = (
    "a guide line is drawn again while its start point lies inside the patient cylinder, "
    "or puts the arm's wrist closer to the shoulder than min_wrist_reach_mm or farther "
    "than max_wrist_reach_mm (checked in that order; the first that holds is the reason)"
)
_SHOULDER_MM = 333.0  # the Panda's shoulder above its base


@dataclass(frozen=True)
class GuideFilter:
    """The geometry the filter checks a guide line against (mm; transmitter frame).

    Attributes
    ----------
    start_distance_mm : float
        ``d``: the start point is ``target + d l_g``.
    patient_axis : ndarray, shape (3,)
        Unit direction of the patient cylinder's axis (through the target).
    patient_radius_mm : float
    shoulder_mm : ndarray, shape (3,)
        The real arm's shoulder.
    wrist_back_mm : float
        Wrist (flange) to needle tip along the needle.
    min_wrist_reach_mm, max_wrist_reach_mm : float
    """

    start_distance_mm: float
    patient_axis: np.ndarray
    patient_radius_mm: float
    shoulder_mm: np.ndarray
    wrist_back_mm: float
    min_wrist_reach_mm: float
    max_wrist_reach_mm: float

    @classmethod
    def from_scenario(cls, scenario, controller=None) -> GuideFilter:
        """The filter of a :class:`~needlekit.studies.puncture_study.PunctureScenario`.

        Parameters
        ----------
        scenario : PunctureScenario
        controller : ControllerSettings, optional
            Gives the patient cylinder (default settings if omitted).

        Returns
        -------
        GuideFilter
        """
        from needlekit.control.controller import ControllerSettings
        from needlekit.control.panda import FLANGE_MM
        from needlekit.control.parameters import pose_from_parameters

        cs = controller or ControllerSettings()
        true_a = scenario.nominal_parameters
        base = pose_from_parameters(true_a[:6])
        axis = np.asarray(cs.patient_axis, dtype=float)
        return cls(
            start_distance_mm=float(scenario.start_distance_mm),
            patient_axis=axis / np.linalg.norm(axis),
            patient_radius_mm=float(cs.patient_radius_mm),
            shoulder_mm=base[:3, 3] + base[:3, 2] * _SHOULDER_MM,
            wrist_back_mm=FLANGE_MM + float(true_a[8]),
            min_wrist_reach_mm=float(scenario.min_wrist_reach_mm),
            max_wrist_reach_mm=float(scenario.max_wrist_reach_mm),
        )

    def codes(self, targets_mm, directions) -> np.ndarray:
        """The verdicts on guide lines as codes: 0 accepted, ``k`` refused for
        ``REFUSAL_REASONS[k - 1]``.

        Parameters
        ----------
        targets_mm : array_like, shape (n, 3)
        directions : array_like, shape (n, 3)
            Unit ``l_g`` (pointing out of the patient).

        Returns
        -------
        ndarray of int, shape (n,)
        """
        targets = np.atleast_2d(np.asarray(targets_mm, dtype=float))
        lg = np.atleast_2d(np.asarray(directions, dtype=float))
        rel = self.start_distance_mm * lg  # start point minus target
        off_axis = np.linalg.norm(
            rel - np.outer(rel @ self.patient_axis, self.patient_axis), axis=1
        )
        wrist = targets + rel + self.wrist_back_mm * lg
        reach = np.linalg.norm(wrist - self.shoulder_mm, axis=1)
        codes = np.zeros(len(lg), dtype=int)
        codes[reach > self.max_wrist_reach_mm] = 3
        codes[reach < self.min_wrist_reach_mm] = 2
        codes[off_axis < self.patient_radius_mm] = 1  # the first check wins
        return codes

    def verdict(self, target_mm, direction) -> str:
        """The verdict on one guide line: :data:`ACCEPTABLE` or a refusal reason.

        Parameters
        ----------
        target_mm, direction : array_like, shape (3,)

        Returns
        -------
        str
        """
        code = int(self.codes(target_mm, direction)[0])
        return ACCEPTABLE if code == 0 else REFUSAL_REASONS[code - 1]


def cylinder_refusal_share(scenario, controller=None) -> float | None:
    """The exact share of the study's random guide lines whose start point lies inside the
    patient cylinder, the same in every octant.

    With the start point ``d l_g`` from the target and the cylinder's axis ``a`` through
    the target, the point is inside when ``|l_g . a| > sqrt(1 - k)``, ``k = (R_p / d)^2``.
    For ``a`` a coordinate axis and the components ``c`` of ``l_g`` uniform in ``[0, 1]``
    (up to sign), that is ``c_a > rho / r`` with ``rho`` the length of the other two
    components and ``r^2 = k / (1 - k)``: the volume under ``1 - rho / r`` over a quarter
    disc of radius ``r``, ``pi r^2 / 12`` (``pi / 15``, 20.9 %, for ``R_p / d = 2 / 3``).

    Parameters
    ----------
    scenario : PunctureScenario
    controller : ControllerSettings, optional

    Returns
    -------
    float or None
        None when the closed form does not apply (the axis is not a coordinate axis, or
        ``k >= 1/2``, where the disc leaves the unit square).
    """
    gf = GuideFilter.from_scenario(scenario, controller)
    k = (gf.patient_radius_mm / gf.start_distance_mm) ** 2
    if k >= 0.5 or np.count_nonzero(np.abs(gf.patient_axis) > 1e-12) != 1:
        return None
    return float(np.pi * k / (1.0 - k) / 12.0)


def _counts(codes: np.ndarray) -> dict:
    n, refused = len(codes), int(np.count_nonzero(codes))
    out = {"draws": n, "refused": refused, "refusal_rate": refused / n}
    for k, reason in enumerate(REFUSAL_REASONS, start=1):
        out[reason] = int(np.count_nonzero(codes == k))
    out["expected_draws_per_trial"] = n / (n - refused) if refused < n else None
    return out


def redraw_filter_rates(
    scenario, *, draws_per_octant: int = FILTER_DRAWS_PER_OCTANT, seed: int = 0
) -> dict:
    """The filter on its own: refusals among random guide lines drawn like the study's.

    Each octant gets ``draws_per_octant`` lines, each with its target uniform in the
    scenario's target cube; no trial is simulated.

    Parameters
    ----------
    scenario : PunctureScenario
    draws_per_octant : int
    seed : int

    Returns
    -------
    dict
        ``rule``, ``draws_per_octant``, ``seed``, ``octants`` (per octant: ``octant``,
        ``draws``, ``refused``, ``refusal_rate``, the count per refusal reason and
        ``expected_draws_per_trial``, ``1 / (1 - rate)``), ``all`` (the four octants
        pooled; its ``refusal_rate`` is the share of trials that would keep a refused line
        without redraws, its ``expected_draws_per_trial`` the mean over the octants, as the
        trials take them in turn) and ``inside_patient_cylinder_exact_share``
        (:func:`cylinder_refusal_share`, the exact value the counts estimate).

    Raises
    ------
    InvalidInputError
        ``draws_per_octant`` is not a whole number >= 1.

    Examples
    --------
    >>> from needlekit.studies.puncture_study import PunctureScenario
    >>> r = redraw_filter_rates(PunctureScenario(), draws_per_octant=100)
    >>> r["all"]["draws"]
    400
    """
    if isinstance(draws_per_octant, bool) or not isinstance(draws_per_octant, int):
        raise InvalidInputError(
            "draws_per_octant", f"expected a whole number, got {draws_per_octant!r}"
        )
    if draws_per_octant < 1:
        raise InvalidInputError("draws_per_octant", f"expected >= 1, got {draws_per_octant}")
    gf = GuideFilter.from_scenario(scenario)
    rng = np.random.default_rng(seed)
    half = scenario.target_cube_mm / 2.0
    centre = np.asarray(scenario.target_center_mm, dtype=float)
    octants, all_codes = [], []
    for name, (sx, sy) in zip(OCTANT_NAMES, OCTANT_SIGNS, strict=True):
        targets = centre + rng.uniform(-half, half, (draws_per_octant, 3))
        c = rng.uniform(0.0, 1.0, (draws_per_octant, 3)) * np.array([sx, sy, 1.0])
        norms = np.linalg.norm(c, axis=1, keepdims=True)
        codes = gf.codes(targets, c / np.maximum(norms, 1e-300))
        octants.append({"octant": name} | _counts(codes))
        all_codes.append(codes)
    pooled = _counts(np.concatenate(all_codes))
    expected = [o["expected_draws_per_trial"] for o in octants]
    pooled["expected_draws_per_trial"] = None if None in expected else float(np.mean(expected))
    return {
        "rule": FILTER_RULE,
        "draws_per_octant": draws_per_octant,
        "seed": seed,
        "octants": octants,
        "all": pooled,
        "inside_patient_cylinder_exact_share": cylinder_refusal_share(scenario),
    }


def _outcome(trials: list[dict]) -> dict:
    aborted = [t for t in trials if not trial_solved(t.get("status", ""))]
    return {
        "count": len(trials),
        "completed": len(trials) - len(aborted),
        "aborted": {
            "count": len(aborted),
            "by_reason": dict(Counter(t.get("reason", "") for t in aborted).most_common()),
            "trials": [t["trial"] for t in aborted],
        },
    }


def redraw_summary(trials: list[dict], redraw_guides: bool) -> dict:
    """How the filter acted in a study: the trials it redrew, the draws it refused and why,
    and the outcome of the trials by the verdict on their first guide line.

    Parameters
    ----------
    trials : list of dict
        Trial outcomes with ``guide_draws``, ``guide_refused`` (refused draws per reason)
        and ``first_guide_verdict``.
    redraw_guides : bool
        Whether the study redrew refused lines (without redraws every trial keeps its
        first line, refused or not).

    Returns
    -------
    dict
        ``enabled``, ``rule``, ``trials``, ``draws``, ``trials_redrawn``,
        ``refused_draws`` (``total`` and per reason), ``first_line_refused`` (``count``,
        per reason, ``trials``) and ``by_first_line`` (per verdict on the first line: the
        trials' ``count``, ``completed`` and ``aborted`` with ``by_reason``). Without
        redraws also ``kept_refused_line`` and ``acceptable_first_line`` (the same
        outcome records): the trials that failed for keeping a refused line are the excess
        of the first over the second.
    """
    refused = {
        r: sum(t.get("guide_refused", {}).get(r, 0) for t in trials) for r in REFUSAL_REASONS
    }
    first = {t["trial"]: t.get("first_guide_verdict", ACCEPTABLE) for t in trials}
    bad = [i for i, v in first.items() if v != ACCEPTABLE]
    out = {
        "enabled": bool(redraw_guides),
        "rule": FILTER_RULE,
        "trials": len(trials),
        "draws": sum(t.get("guide_draws", 1) for t in trials),
        "trials_redrawn": sum(t.get("guide_draws", 1) > 1 for t in trials),
        "refused_draws": {"total": sum(refused.values())} | refused,
        "first_line_refused": {"count": len(bad)}
        | {r: sum(v == r for v in first.values()) for r in REFUSAL_REASONS}
        | {"trials": bad},
        "by_first_line": {
            v: _outcome([t for t in trials if first[t["trial"]] == v])
            for v in (ACCEPTABLE, *REFUSAL_REASONS)
        },
    }
    if not redraw_guides:
        out["kept_refused_line"] = _outcome([t for t in trials if first[t["trial"]] != ACCEPTABLE])
        out["acceptable_first_line"] = out["by_first_line"][ACCEPTABLE]
    return out
