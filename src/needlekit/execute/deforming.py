"""The ``physical`` truth: the needle that bends by mechanics, in an organ that deforms.

Two models, coupled at the rod's solve rate (40 Hz):

- the needle (:class:`~needlekit.execute.physical.MechanicsTruth`: an elastic rod held by
  the tissue along the channel its tip cuts, docs/mechanics.md);
- the organ (:class:`~needlekit.tissue.runtime.DeformingTissue`: linear elasticity on the
  organ's tetrahedral mesh from its Med-RAD mask, condensed onto the plan's corridor, the
  target and the vessels and airways beside it; docs/tissue.md).

Each solve of the rod gives the tissue's loads on the needle (along the shaft, and the
bevel's load at the tip). The organ takes the opposite of the tip's load (the bevel's
lateral load and the cutting resistance along the tangent) and deforms: the target, the
corridor and the vessels and airways beside it move. The coupling is one way, and why:

- The shaft's lateral loads are the foundation's reactions, the tissue's local answer to
  the rod, which the Winkler foundation already models; the organ is not given them too
  (that would count the local compliance twice).
- The channel's anchors do not follow the organ's displacement under the needle's own
  load: at the load the elastic solution is singular (Kelvin's ``1 / r``) and a mesh's
  answer there is its cell size's, not the tissue's; measured, moving the anchors by it
  threw the rod millimetres per step. The rod's local answer to its own load is the
  foundation's and the bevel's model. What moves the target is what the organ answers
  away from the load: the target, ahead of the tip, is pushed on.
- Friction along the shaft is not modelled (docs/mechanics.md): the organ is pushed at the
  tip only.

**Breathing** moves the organ through the same mesh (docs/tissue.md: the lung's pleura
by ``w d``, ``w`` from 0 at the apex to 1 at the base; the liver's ligament surface by
``d``): the loop hands the truth each tick's displacement ``d(t)`` (``breathe``), the
target and the structures move by ``B d`` besides the needle's push, and a needle let go
rides with the tissue at its tip (``riding``), not with a rigid ``d``.

The truth then has these of the capabilities the loop looks for
(:mod:`needlekit.execute.plugins`): ``target_mm()`` (the target where the tissue has
carried it: the loop's final error is measured to it, in the world), ``shaft_loads()``,
``breathe(d)``, ``riding(d0, d1)`` and ``to_rest(points)``: the material points now at
world points, the organ's breathing displacement inverted
(:meth:`~needlekit.tissue.runtime.DeformingTissue.to_rest` with ``loads=False``). The run
maps each point of the tip's path when it records it, so ``points_rest_mm`` are the
points of the organ at rest the tip passed through, and the path's clearance is judged
there, against the masks. The needle's own push is not inverted, and why: at the load
the organ's answer is its mesh cell's (Kelvin's ``1 / r`` regularised by a cell of about
10 mm), 4.7-8.6 mm under a 0.3 N tip load on lungs 1 and 3; mapping the path back
through it put the points of its first millimetres 3-5 mm behind the tip, outside the lung
and into the chest wall's obstacles (4 of 4 sliding-pleura runs of lung 3 crossed there).
The tip's own load's local answer is the rod's (its foundation and the bevel's model):
the material it cuts is where it is.

:class:`TissueModel` names the organ and the corridor; its precomputation (mesh,
factorisation, condensed compliance) goes through the prepared-anatomy cache and is loaded
once per process.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import blake3
import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.physical import MechanicsTruth, mechanics_truth
from needlekit.io.anatomy_cache import file_digest
from needlekit.io.record_cache import load_record, store_record
from needlekit.tissue.compliance import load_cached, precompute, resample_polyline
from needlekit.tissue.fem import BOUNDARY_MODES
from needlekit.tissue.medrad_organ import ORGAN_FILES, organ_files, organ_inputs
from needlekit.tissue.runtime import DeformingTissue

__all__ = ["DeformingTruth", "TissueModel", "load_compliance", "physical_truth", "tissue_model_for"]


@dataclass(frozen=True)
class TissueModel:
    """The deforming organ of one execution: what its precomputation is made from.

    Attributes
    ----------
    organ : str
        ``"lung"`` or ``"liver"``.
    folder : str
        The Med-RAD patient folder.
    corridor_mm : tuple of float
        The plan's path, flattened (x, y, z per point), a point every 1.5 mm.
    target_mm : tuple of float
    boundary_mode : str
        ``"organ"`` (the organ's held surfaces, docs/tissue.md) or ``"sliding"``.
    radius_mm : float
        Vessels and airways within this of the corridor are tracked.
    per_structure : int
        At most this many tracked points per structure.
    cache_dir : str or None
        The prepared-anatomy cache the precomputation goes through (None: the default,
        ``$NEEDLEKIT_CACHE_DIR`` or the user's).
    use_cache : bool
        False: precompute in memory, nothing read from or written to a cache.
    """

    organ: str
    folder: str
    corridor_mm: tuple
    target_mm: tuple
    boundary_mode: str = "organ"
    radius_mm: float = 15.0
    per_structure: int = 100
    cache_dir: str | None = None
    use_cache: bool = True

    def __post_init__(self) -> None:
        if self.organ not in ORGAN_FILES:
            raise InvalidInputError("organ", f"expected one of {', '.join(ORGAN_FILES)}, got {self.organ!r}")
        if self.boundary_mode not in BOUNDARY_MODES:
            raise InvalidInputError(
                "boundary_mode", f"expected one of {', '.join(BOUNDARY_MODES)}, got {self.boundary_mode!r}"
            )
        if self.boundary_mode == "sliding" and self.organ != "lung":
            raise InvalidInputError("boundary_mode", f"sliding is the lung's pleura, not the {self.organ}'s")

    def corridor(self) -> np.ndarray:
        """The corridor's points, shape (m, 3).

        Returns
        -------
        ndarray
        """
        return np.asarray(self.corridor_mm, dtype=np.float64).reshape(-1, 3)

    def compliance(self):
        """The precomputed organ (meshed, factorised, condensed; through the cache), once
        per process.

        Returns
        -------
        needlekit.tissue.compliance.Compliance
        """
        return _compliance(self)

    def record(self) -> dict:
        """What ``execute.json`` says of the organ.

        Returns
        -------
        dict
        """
        c = self.compliance()
        return {
            "organ": self.organ,
            "folder": self.folder,
            "boundary_mode": self.boundary_mode,
            "mesh_tetrahedra": int(c.mesh.n_tets),
            "mesh_nodes": int(c.mesh.n_nodes),
            "corridor_points": len(c.corridor_mm),
            "tracked_points": len(c.tracked_mm),
            "pinned_points": self.pinned(),
            "material": c.info.get("material"),
            "timings_s": c.info.get("timings_s"),
        }

    def pinned(self) -> dict:
        """The tracked points the needle cannot move (within a cell of a held surface,
        :meth:`~needlekit.tissue.compliance.Compliance.pinned`), counted by what they are
        (``"target"``: 1 when the target is one of them). Empty when every one can move.

        Returns
        -------
        dict of str to int
        """
        c = self.compliance()
        out: dict[str, int] = {}
        for label, pinned in zip(c.tracked_labels, c.pinned(), strict=True):
            if pinned:
                out[label] = out.get(label, 0) + 1
        return out


@functools.lru_cache(maxsize=4)
def _compliance(model: TissueModel):
    return load_compliance(model)


def load_compliance(model: TissueModel, cache_dir=None):
    """Mesh, factorise and condense ``model``'s organ, through the prepared-anatomy cache
    (:func:`needlekit.tissue.compliance.precompute`; :meth:`TissueModel.compliance` keeps
    the answer for the process).

    The precomputation's key is made from the organ body and the tracked points, which
    take reading and binarising the masks (3-4 s for a lung). A run that has stored it
    leaves a record under a fast key (the mask files' digests and ``model``'s fields,
    :mod:`needlekit.io.record_cache`) naming that entry, so a later run with the same
    model opens it without reading a mask.

    Parameters
    ----------
    model : TissueModel
    cache_dir : path-like, optional
        Another cache folder (a benchmark's cold run; default: ``model.cache_dir``).

    Returns
    -------
    needlekit.tissue.compliance.Compliance
    """
    read = _organ_inputs_shared if cache_dir is None else _read_organ
    cache_dir = model.cache_dir if cache_dir is None else cache_dir
    fast = _fast_inputs(model) if model.use_cache else None
    if fast is not None and (known := load_record(cache_dir, "tissue-key", fast)) is not None:
        comp = load_cached(cache_dir, str(known.get("label")), str(known.get("key")))
        if comp is not None:
            return comp
    inputs = (model.folder, model.organ, model.corridor_mm, model.target_mm, model.radius_mm,
              model.per_structure)  # fmt: skip
    # the process's own models (no other cache folder) keep the last masks read: a
    # model's other boundary mode is made from the same ones. A run given its own cache
    # folder (a benchmark's cold run) reads them afresh.
    body, affine, tracked, labels = read(*inputs)
    comp = precompute(body, affine, model.organ, model.corridor(), tracked, labels,
                      seed_mm=np.asarray(model.target_mm), boundary_mode=model.boundary_mode,
                      use_cache=model.use_cache, cache_dir=cache_dir)  # fmt: skip
    if fast is not None and "cache_key" in comp.info:
        store_record(cache_dir, "tissue-key", fast,
                     {"label": comp.info["cache_label"], "key": comp.info["cache_key"]},
                     f"{model.organ} tissue (its fast key)")  # fmt: skip
    return comp


def _read_organ(folder, organ, corridor_mm, target_mm, radius_mm, per_structure):
    body, affine, tracked, labels = organ_inputs(
        folder, organ, np.asarray(corridor_mm, dtype=np.float64).reshape(-1, 3), target_mm,
        radius_mm, per_structure,
    )  # fmt: skip
    body.flags.writeable = False  # shared by the models made from it: read only
    return body, affine, tracked, tuple(labels)


def _organ_inputs_shared(*inputs):
    body, affine, tracked, labels = _organ_inputs_last(*inputs)
    return body, affine.copy(), tracked.copy(), labels


#: The last organ read (its body alone is tens of MB): the models of one organ and
#: corridor that differ in their boundary mode alone share it.
_organ_inputs_last = functools.lru_cache(maxsize=1)(_read_organ)


def _fast_inputs(model: TissueModel) -> dict:
    """What the precomputation of ``model`` is made from, known before a mask is read: the
    digest of every mask file :func:`~needlekit.tissue.medrad_organ.organ_inputs` reads,
    and the model's fields."""
    files = organ_files(model.folder, model.organ)
    return {
        "masks": {p.name: file_digest(p) for p in files},
        "organ": model.organ,
        "corridor": blake3.blake3(model.corridor().tobytes()).hexdigest(),
        "target_mm": [float(v) for v in model.target_mm],
        "boundary_mode": model.boundary_mode,
        "radius_mm": float(model.radius_mm),
        "per_structure": int(model.per_structure),
    }


def tissue_model_for(scenario, plan, goal_mm, boundary_mode: str = "organ", *, cache_dir=None,
                     use_cache: bool = True) -> TissueModel | None:  # fmt: skip
    """The deforming organ of a scenario with a Med-RAD base (None for any other).

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario
    plan : SteerablePlan
        Its path is the corridor.
    goal_mm : array_like, shape (3,)
    boundary_mode : str
    cache_dir : path-like, optional
    use_cache : bool
        As :class:`TissueModel`'s.

    Returns
    -------
    TissueModel or None
    """
    from needlekit.io.medrad import MedradCase

    base = getattr(scenario, "base", None)
    if not isinstance(base, MedradCase) or base.organ not in ORGAN_FILES:
        return None
    path = np.asarray(plan.points_mm(0.5), dtype=np.float64)
    corridor = resample_polyline(path, 1.5)
    goal = np.asarray(goal_mm, dtype=np.float64)
    return TissueModel(base.organ, str(base.folder), tuple(np.round(corridor, 6).ravel().tolist()),
                       tuple(float(v) for v in goal), boundary_mode,
                       cache_dir=None if cache_dir is None else str(cache_dir),
                       use_cache=bool(use_cache))  # fmt: skip


class DeformingTruth(MechanicsTruth):
    """The rod in the deforming organ (see the module notes).

    Parameters
    ----------
    needle : needlekit.mechanics.insertion.MechanicalNeedle
    r_min_mm, solve_rate_hz : float
        As :class:`~needlekit.execute.physical.MechanicsTruth`.
    tissue : needlekit.tissue.runtime.DeformingTissue

    Attributes
    ----------
    dropped_loads : int
        Loads the organ could not take (farther than its corridor reaches).
    target_rest_mm : ndarray, shape (3,)
    max_target_displacement_mm : float
    """

    def __init__(self, needle, r_min_mm: float, solve_rate_hz: float, tissue) -> None:
        self.tissue = tissue
        self.breathing_mm = np.zeros(3)
        self.dropped_loads = 0
        self.target_rest_mm = tissue.target_mm().copy()
        self.max_target_displacement_mm = 0.0
        super().__init__(needle, r_min_mm, solve_rate_hz)

    def _flush(self) -> None:
        solved = self._len > 0.0
        super()._flush()
        if not solved:
            return
        pts, forces = self.needle.shaft_loads()
        pts = pts + self.offset_mm
        if len(pts):  # the tip's load: the bevel's lateral load and the cutting resistance
            keep = self._near_corridor(pts[-1:])
            self.dropped_loads += int((~keep).sum())
            self.tissue.apply(pts[-1:][keep], -forces[-1:][keep], breathing=self.breathing_mm)
        moved = float(np.linalg.norm(self.tissue.target_displacement_mm))
        self.max_target_displacement_mm = max(self.max_target_displacement_mm, moved)

    def _near_corridor(self, pts: np.ndarray) -> np.ndarray:
        reach = self.tissue.max_offset_mm
        now = self.tissue.positions_mm("corridor")
        d = np.min(np.linalg.norm(pts[:, None, :] - now[None, :, :], axis=2), axis=1)
        return d <= reach

    def target_mm(self) -> np.ndarray:
        """Where the tissue has carried the target now (RAS mm).

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.tissue.target_mm()

    def breathe(self, breathing_mm) -> None:
        """The organ's breathing displacement ``d`` (mm) from now on (module notes).

        Parameters
        ----------
        breathing_mm : array-like, shape (3,)

        Returns
        -------
        None
        """
        self.tissue.breathe(breathing_mm)
        self.breathing_mm = np.array(breathing_mm, dtype=np.float64).reshape(3)
        moved = float(np.linalg.norm(self.tissue.target_displacement_mm))
        self.max_target_displacement_mm = max(self.max_target_displacement_mm, moved)

    def riding(self, d0, d1) -> np.ndarray:
        """How far the tissue at the tip moves as the breathing goes from ``d0`` to ``d1``
        (mm, world): a needle let go rides with it.

        Parameters
        ----------
        d0, d1 : array-like, shape (3,)

        Returns
        -------
        ndarray, shape (3,)
        """
        at = self.to_rest(self.pose[None, :3, 3])
        d = np.asarray(d1, dtype=np.float64) - np.asarray(d0, dtype=np.float64)
        return self.tissue.breathing_field(at, d)[0]

    def to_rest(self, points) -> np.ndarray:
        """The points of the organ at rest now at world ``points``, its breathing inverted
        (module notes).

        Parameters
        ----------
        points : array-like, shape (k, 3)

        Returns
        -------
        ndarray, shape (k, 3)
        """
        return self.tissue.to_rest(points, loads=False)

    def shaft_loads(self) -> dict:
        """The needle's loads (as :meth:`MechanicsTruth.shaft_loads`) and the organ's
        answer: the target's displacement now and its largest, the loads it could not take.

        Returns
        -------
        dict
        """
        out = super().shaft_loads()
        out["target_displacement_mm"] = float(np.linalg.norm(self.tissue.target_displacement_mm))
        out["max_target_displacement_mm"] = self.max_target_displacement_mm
        out["dropped_loads"] = self.dropped_loads
        return out


def physical_truth(setup) -> DeformingTruth:
    """The ``physical`` truth (:data:`needlekit.execute.plugins.TRUTHS`): the ``mechanics``
    truth's rod in the run's deforming organ (``settings.tissue``, a :class:`TissueModel`).

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    DeformingTruth

    Raises
    ------
    InvalidInputError
        ``--truth``: the run has no organ to deform (a scenario without a Med-RAD base).
    """
    from needlekit.mechanics.insertion import MechanicalNeedle

    model = setup.settings.tissue
    if model is None:
        raise InvalidInputError(
            "--truth", "physical deforms the scenario's organ: it needs a Med-RAD scenario"
        )
    m = setup.settings.mechanics
    needle = MechanicalNeedle(setup.start_pose, m.needle_spec(), m.tissue_spec(),
                              rng=setup.rng, inhomogeneity=m.inhomogeneity)  # fmt: skip
    return DeformingTruth(needle, setup.r_min_mm, m.solve_rate_hz,
                          DeformingTissue(model.compliance()))  # fmt: skip


def _physical_parameters(settings) -> dict:

    out = {"mechanics": mechanics_truth.parameters(settings)}
    if settings.tissue is not None:
        out["tissue"] = settings.tissue.record()
    return out


physical_truth.parameters = _physical_parameters
