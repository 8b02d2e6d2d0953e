"""The settings a run with a physical truth needs, in one place for ``needlekit execute``
and ``study execute-lungs``: the needle and tissue (``settings.mechanics``), the deforming
organ for ``physical`` (``settings.tissue``), and the loop's own model calibrated on the
truth (``settings.model``), never the simulator's parameters.

The calibration inserts the needle alone (``mechanics``, even for ``physical``): the
organ's motion is for the loop to see through its sensors, not for its model to learn.
"""

from __future__ import annotations

from dataclasses import replace

from needlekit.errors import InvalidInputError
from needlekit.execute.calibration import CalibrationSettings, calibrate_truth
from needlekit.execute.physical import MechanicsSettings

__all__ = ["PHYSICAL_TRUTHS", "physical_settings"]

#: The truths whose loop is given a calibrated model (the others are given the simulator's
#: radius and noise: their needle is the planner's own model).
PHYSICAL_TRUTHS: tuple[str, ...] = ("mechanics", "physical")


def physical_settings(settings, scenario, plan, goal_mm, r_min_mm: float, *,
                      mechanics: MechanicsSettings, boundary: str = "organ",
                      insertions: int = 24, seed: int = 0):  # fmt: skip
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

        model = tissue_model_for(scenario, plan, goal_mm, boundary)
        if model is None:
            raise InvalidInputError(
                "truth", "physical deforms the scenario's organ: it needs a Med-RAD scenario"
            )
        s = replace(s, tissue=model)
    on = replace(s, models=replace(s.models, truth="mechanics")) if truth == "physical" else s
    cal = calibrate_truth(on, plan.start_pose, float(r_min_mm),
                          CalibrationSettings(curved=insertions, straight=max(2, insertions // 2),
                                              seed=seed))  # fmt: skip
    return replace(s, model=cal)
