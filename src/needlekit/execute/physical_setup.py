"""The settings a run with a physical truth needs, in one place for ``needlekit execute``
and ``study execute-lungs``: the needle and tissue (``settings.mechanics``), the deforming
organ for ``physical`` (``settings.tissue``), and the loop's own model calibrated on the
truth (``settings.model``), never the simulator's parameters.

The calibration inserts the needle alone (``mechanics``, even for ``physical``): the
organ's motion is for the loop to see through its sensors, not for its model to learn.
It is kept in the prepared-anatomy cache (:mod:`needlekit.io.record_cache`) under
everything it is computed from: the needle and tissue, the start pose, the radius, the
calibration's settings (and needlekit's source), so a second run of the same plan and
needle reads the same model back instead of inserting 36 needles again (10-15 s).
"""

from __future__ import annotations

from dataclasses import asdict, replace

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.calibration import Calibration, CalibrationSettings, calibrate_truth
from needlekit.execute.physical import MechanicsSettings, mechanics_truth
from needlekit.execute.plugins import TRUTHS
from needlekit.io.record_cache import load_record, store_record

__all__ = ["PHYSICAL_TRUTHS", "physical_settings"]

#: The truths whose loop is given a calibrated model (the others are given the simulator's
#: radius and noise: their needle is the planner's own model).
PHYSICAL_TRUTHS: tuple[str, ...] = ("mechanics", "physical")


def physical_settings(settings, scenario, plan, goal_mm, r_min_mm: float, *,
                      mechanics: MechanicsSettings, boundary: str = "organ",
                      insertions: int = 24, seed: int = 0, cache_dir=None,
                      use_cache: bool = True):  # fmt: skip
    """``settings`` with the mechanics, the organ (``physical``) and the calibrated model.

    Parameters
    ----------
    settings : needlekit.execute.run.ExecutionSettings
        Its ``models.truth`` is ``"mechanics"`` or ``"physical"``.
    scenario : needlekit.scenario.loading.Scenario
        A Med-RAD scenario for ``physical``.
    plan : SteerablePlan
        Its path is the organ's corridor; its start is the calibration's.
    goal_mm : array_like, shape (3,)
    r_min_mm : float
        The plan's radius (the loop's command unit).
    mechanics : MechanicsSettings
    boundary : str
        The organ's boundary (``"organ"`` or ``"sliding"``).
    insertions : int
        Curved calibration insertions (and half as many straight ones, at least 2).
    seed : int
    cache_dir : path-like, optional
        The prepared-anatomy cache the organ's precomputation and the calibration go
        through (default: ``$NEEDLEKIT_CACHE_DIR`` or the user's).
    use_cache : bool
        False: both computed in memory, nothing read or written.

    Returns
    -------
    ExecutionSettings

    Raises
    ------
    InvalidInputError
        (``truth``) ``physical`` on a scenario with no organ to mesh; (``truth``) a truth
        that is not physical.
    """
    truth = settings.models.truth
    if truth not in PHYSICAL_TRUTHS:
        raise InvalidInputError("truth", f"expected one of {', '.join(PHYSICAL_TRUTHS)}, got {truth!r}")
    s = replace(settings, mechanics=mechanics)
    if truth == "physical":
        from needlekit.execute.deforming import tissue_model_for

        model = tissue_model_for(scenario, plan, goal_mm, boundary, cache_dir=cache_dir,
                                 use_cache=use_cache)  # fmt: skip
        if model is None:
            raise InvalidInputError(
                "truth", "physical deforms the scenario's organ: it needs a Med-RAD scenario"
            )
        s = replace(s, tissue=model)
    on = replace(s, models=replace(s.models, truth="mechanics")) if truth == "physical" else s
    how = CalibrationSettings(curved=insertions, straight=max(2, insertions // 2), seed=seed)
    cal = _calibration(on, plan.start_pose, float(r_min_mm), how, cache_dir, use_cache)
    return replace(s, model=cal)


def _calibration(settings, start_pose, r_min_mm: float, how: CalibrationSettings,
                 cache_dir, use_cache: bool) -> Calibration:  # fmt: skip
    """:func:`calibrate_truth`, through the cache when the truth is the built-in
    ``mechanics`` (whose inputs are known: a registered replacement is calibrated every
    time); ``use_cache`` False: no cache."""
    if not use_cache or TRUTHS.get(settings.models.truth) is not mechanics_truth:
        return calibrate_truth(settings, start_pose, r_min_mm, how)
    m = settings.mechanics
    inputs = {
        "mechanics": asdict(m), "needle_spec": asdict(m.needle_spec()),
        "tissue_spec": asdict(m.tissue_spec()), "calibration": asdict(how),
        "start_pose": np.asarray(start_pose, dtype=np.float64).tolist(), "r_min_mm": r_min_mm,
    }  # fmt: skip
    record = load_record(cache_dir, "calibration", inputs)
    if record is not None:
        try:
            return Calibration.from_dict(record, "the cached calibration")
        except InvalidInputError:  # written by a build that knew other fields: redo it
            pass
    cal = calibrate_truth(settings, start_pose, r_min_mm, how)
    store_record(cache_dir, "calibration", inputs, cal.to_dict(), f"{m.needle} needle in {m.tissue}")
    return cal
