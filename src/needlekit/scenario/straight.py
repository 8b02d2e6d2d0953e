"""The straight multi-needle problem and the coverage region a scenario's ``straight``
block describes (Liu et al. 2016)."""

from __future__ import annotations

from dataclasses import replace as _replace
from pathlib import Path

import numpy as np

from needlekit.anatomy.fields import union
from needlekit.errors import InvalidInputError

__all__ = ["coverage_region", "multi_problem_from_scenario"]


def multi_problem_from_scenario(scenario, *, targets_mm=None):
    """The straight multi-needle problem a scenario's ``straight`` block describes.

    The needle is the scenario's (radius half its diameter plus nothing: gamma is the
    block's safety distance; ``max_length_mm``). Sigma's z axis (``up``) defaults to the
    reverse of the start's z axis (the direction the needle comes from), else RAS +z; the
    approach cone, when given, is around that same direction.

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario or path-like
    targets_mm : array_like, shape (k, 3), optional
        Replace the block's targets.

    Returns
    -------
    problem : MultiNeedleProblem
    options : dict
        The planner settings of the block (``resolution_deg``, ``objective``, ``order``).

    Raises
    ------
    InvalidInputError
        No ``straight`` block, or a field out of range (named).
    """
    from needlekit.planning.straight.deformation import GridDeformation, NeedleDragDeformation
    from needlekit.planning.straight.planner import MultiNeedleProblem
    from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
    from needlekit.scenario.loading import Scenario, load_scenario

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    block = dict(sc.straight or {})
    if not block:
        raise InvalidInputError("straight", "the scenario has no straight block")
    if targets_mm is not None:
        targets = np.asarray(targets_mm, dtype=float)
    elif isinstance(block["targets"], str):  # coverage: chosen later; a stand-in till then
        field = sc.scene[block["coverage"]["structure"]].field
        targets = np.asarray(field.bounds(), dtype=float).reshape(2, 3).mean(axis=0)[None]
    else:
        targets = block["targets"]
    came_from = (
        None if sc.start is None or sc.start.world_T_tip is None else -sc.start.world_T_tip[:3, 2]
    )
    up = block.get("up", came_from if came_from is not None else np.array([0.0, 0.0, 1.0]))
    kw = {}
    for key in ("gamma_mm", "theta_range_deg", "phi_range_deg", "max_normal_angle_deg"):
        if key in block:
            kw[key] = block[key]
    if "approach_cone_deg" in block:
        if came_from is None:
            raise InvalidInputError(
                "straight.approach_cone_deg", "needs a start pose (its reversed z is the axis)"
            )
        kw["approach_direction"] = came_from
        kw["approach_cone_deg"] = block["approach_cone_deg"]
    needle = StraightNeedle(0.5 * sc.needle.diameter_mm, sc.needle.max_length_mm)
    scene = _body_with_targets(sc, block["entry_surface"])
    problem = StraightProblem(
        scene, np.asarray(targets)[0], block["entry_surface"], needle, up=up, **kw
    )
    deformation = block.get("deformation", "none")
    if deformation == "needle_drag":
        model = NeedleDragDeformation()
    elif isinstance(deformation, dict):
        model = GridDeformation(deformation["grid"])
    else:
        model = None
    options = {k: block[k] for k in ("resolution_deg", "objective", "order") if k in block}
    return MultiNeedleProblem(problem, targets, model), options


def _body_with_targets(sc, entry_surface: str):
    """The scene, with a Med-RAD organ's entry surface closed over its nodules.

    Med-RAD's liver (and lung) masks leave the nodules out: the organ's field is positive
    inside a nodule, so a target there would lie outside the body. The body is the organ
    together with its targets (their union); its outer surface is still the capsule.
    """
    from needlekit.anatomy.scene import Role, Scene
    from needlekit.io.medrad import MedradCase

    if not isinstance(sc.base, MedradCase) or entry_surface not in sc.scene:
        return sc.scene
    organ = sc.scene[entry_surface]
    nodules = [s.field for s in sc.scene.by_role(Role.TARGET)]
    if organ.role is not Role.ALLOWED_REGION or not nodules:
        return sc.scene
    body = _replace(organ, field=union(organ.field, *nodules))
    structures = [body if s.name == entry_surface else s for s in sc.scene.structures]
    return Scene(structures, name=sc.scene.name, obstacle_field=sc.scene.obstacle_field())


def coverage_region(scenario, problem):
    """The tumour-plus-margin region and zone of a scenario's ``straight.coverage`` block.

    The tumour is the block's ``structure``: its mask file when it has one (a Med-RAD
    nodule's NIfTI, on its own grid), else its field voxelised at ``voxel_mm``
    (``signed_distance <= 0``). With ``clip_to_body`` the margin counts only inside the
    problem's entry surface.

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario
    problem : StraightProblem
        From :func:`multi_problem_from_scenario` (its entry surface is the body).

    Returns
    -------
    region : TargetRegion
    settings : dict
        The block: ``zone`` (AblationZone), ``margin_mm``, ``max_needles``,
        ``coverage_goal``, ``structure``, ``voxel_mm``, ``clip_to_body``.
    """
    from needlekit.planning.straight.ablation import clip_region, voxelise
    from needlekit.planning.straight.coverage import target_region

    settings = dict((scenario.straight or {}).get("coverage") or {})
    if not settings:
        raise InvalidInputError("straight.targets", "expected targets: coverage")
    s = scenario.scene[settings["structure"]]
    src = Path(s.source) if s.source else None
    if src is not None and src.suffix in (".gz", ".nii", ".nrrd", ".mha") and src.is_file():
        from needlekit.io.volumes import read_mask

        m = read_mask(src)
        region = target_region(m.data, m.affine, settings["margin_mm"])
    else:
        mask, affine = voxelise(s.field, settings["voxel_mm"])
        region = target_region(mask, affine, settings["margin_mm"])
    if settings["clip_to_body"]:
        region = clip_region(region, problem.scene[problem.entry_surface].field)
    return region, settings
