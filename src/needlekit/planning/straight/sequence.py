"""Several straight needles, one after another (Liu et al. 2016, Fig. 4).

The procedure: choose the order of insertion; for each needle in turn, take its target
(displaced by the tissue deformation the needles placed so far cause), compute its CFRW
with the anatomy and the placed needles as obstacles, choose the optimal trajectory in it,
place the needle (it becomes an obstacle, tube and head), update the targets, and repeat.

Order. With up to :data:`EXHAUSTIVE_ORDER_MAX` needles every order is tried; orders are
ranked on the rigid anatomy (each target's CFRW map computed once, the placed needles'
tubes tested in closed form against every direction of it), by the number of needles
placed, then the total insertion length. The best order is then planned in full: with the
deformation, the placed needles' bodies (heads included) and certified clearances. Beyond
that many needles, a greedy order: next, the target whose CFRW (given the needles placed)
has the fewest directions left (the most constrained first).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import numpy as np

from needlekit.anatomy.needle_body import LIU_HEAD, NeedleBody
from needlekit.errors import InvalidInputError
from needlekit.geometry.segments import segment_distances
from needlekit.planning.straight.cfrw import Blocked, CFRWMap, cfrw_map
from needlekit.planning.straight.entry import (
    Entry,
    Objective,
    best_direction,
    certified_best,
)
from needlekit.planning.straight.problem import StraightProblem
from needlekit.records import Status, enum_of, field_of

__all__ = ["EXHAUSTIVE_ORDER_MAX", "MultiNeedlePlan", "NeedleRecord", "plan_needles"]

#: Up to this many needles every insertion order is tried (6! = 720 orders).
EXHAUSTIVE_ORDER_MAX: int = 6


@dataclass(frozen=True)
class NeedleRecord:
    """One needle of a multi-needle plan.

    Attributes
    ----------
    order : int
        Insertion order (1 = first).
    target_index : int
        Which of the given targets.
    planned_target_mm : ndarray, shape (3,)
        The target as given.
    target_mm : ndarray, shape (3,)
        The target aimed at: displaced by the deformation of the needles before it.
    entry : Entry or None
        The chosen trajectory (None: no trajectory in its CFRW).
    needle_clearance_mm : float
        Certified clearance of its tube from the needles placed before it (``inf`` for
        the first).
    blocked : dict
        Its CFRW's directions per blocking reason (:class:`~.cfrw.Blocked`).
    """

    order: int
    target_index: int
    planned_target_mm: np.ndarray
    target_mm: np.ndarray
    entry: Entry | None
    needle_clearance_mm: float
    blocked: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready record (an item of ``multi.json``'s ``needles``).

        Returns
        -------
        dict
        """
        e = self.entry
        return {
            "order": self.order,
            "target_index": self.target_index,
            "planned_target_mm": np.round(self.planned_target_mm, 6).tolist(),
            "target_mm": np.round(self.target_mm, 6).tolist(),
            "entry_mm": None if e is None else np.round(e.entry_mm, 6).tolist(),
            "length_mm": None if e is None else e.length_mm,
            "clearance_mm": None if e is None else e.clearance_mm,
            "needle_clearance_mm": None
            if not np.isfinite(self.needle_clearance_mm)
            else float(self.needle_clearance_mm),
            "theta_deg": None if e is None else float(np.degrees(e.theta_rad)),
            "phi_deg": None if e is None else float(np.degrees(e.phi_rad)),
            "normal_angle_deg": None if e is None else e.normal_angle_deg,
            "blocked": self.blocked,
        }

    @classmethod
    def from_dict(cls, row: dict, where: str) -> NeedleRecord:
        """A needle from its record, as :meth:`to_dict` writes it.

        Parameters
        ----------
        row : dict
        where : str
            Names the record in messages.

        Returns
        -------
        NeedleRecord

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named).
        """
        blocked = field_of(row, "blocked", where, "dict")
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in blocked.values()):
            raise InvalidInputError(f"{where}: blocked", "expected whole-number counts")
        nc = field_of(row, "needle_clearance_mm", where, optional=True)
        return cls(
            field_of(row, "order", where, "int"),
            field_of(row, "target_index", where, "int"),
            field_of(row, "planned_target_mm", where, "point"),
            field_of(row, "target_mm", where, "point"),
            Entry.from_dict(row, where),
            float("inf") if nc is None else float(nc),
            dict(blocked),
        )


@dataclass(frozen=True)
class MultiNeedlePlan:
    """The outcome of :func:`plan_needles`.

    Attributes
    ----------
    needles : tuple of NeedleRecord
        In insertion order.
    order : tuple of int
        Target indices in insertion order.
    solved : bool
        Every needle has a trajectory.
    orders_tried : int
    gamma_mm, needle_radius_mm : float
    reason : str
        Why not solved ("" when solved): the first needle without a trajectory and what
        blocks its directions, or where the budget ran out.
    maps : tuple of CFRWMap
        Each needle's CFRW map in insertion order, as its trajectory was chosen on it
        (for reports; not in :meth:`to_dict`).
    status : Status or None
        ``SOLVED``; ``INFEASIBLE`` when a needle has no trajectory in its CFRW; a budget
        stop is ``APPROXIMATE`` with the needles placed before it, or ``TIMEOUT`` with
        none (never ``INFEASIBLE``). None (the default) derives it from ``solved``:
        ``SOLVED`` or ``INFEASIBLE``.
    """

    needles: tuple
    order: tuple
    solved: bool
    orders_tried: int
    gamma_mm: float
    needle_radius_mm: float
    reason: str = ""
    maps: tuple = field(default=(), repr=False, compare=False)
    status: Status | None = None

    def __post_init__(self) -> None:
        if self.status is None:
            status = Status.SOLVED if self.solved else Status.INFEASIBLE
            object.__setattr__(self, "status", status)
        elif (self.status is Status.SOLVED) != bool(self.solved):
            raise InvalidInputError(
                "status", f"{self.status.value} does not go with solved={self.solved}"
            )

    def to_dict(self) -> dict:
        """JSON-ready record (the ``multi.json`` format).

        Returns
        -------
        dict
        """
        return {
            "status": self.status.value,
            "reason": self.reason,
            "gamma_mm": self.gamma_mm,
            "needle_radius_mm": self.needle_radius_mm,
            "order": list(self.order),
            "orders_tried": self.orders_tried,
            "needles": [n.to_dict() for n in self.needles],
        }

    @classmethod
    def from_dict(cls, data: dict, where: str) -> MultiNeedlePlan:
        """A multi-needle plan from its ``multi.json`` record, as :meth:`to_dict` writes
        it (without its CFRW maps).

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.

        Returns
        -------
        MultiNeedlePlan
            Solved when every target of ``order`` has a needle with a trajectory; its
            status as recorded (records without a status read as solved or infeasible).

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it, or a status that does not go with
            the needles (named).
        """
        rows = field_of(data, "needles", where, "list")
        needles = tuple(
            NeedleRecord.from_dict(row, f"{where}: needles[{i}]") for i, row in enumerate(rows)
        )
        order = field_of(data, "order", where, "list")
        if not all(isinstance(k, int) and not isinstance(k, bool) for k in order):
            raise InvalidInputError(f"{where}: order", "expected target indices")
        placed = len(needles) == len(order)  # a budget stop leaves targets out
        solved = bool(needles) and placed and all(n.entry is not None for n in needles)
        given = field_of(data, "status", where, "str", optional=True)
        status = None if given is None else enum_of(Status, given, f"{where}: status")
        if status is not None and (status is Status.SOLVED) != solved:
            msg = f"{status.value} does not go with the needles' trajectories"
            raise InvalidInputError(f"{where}: status", msg)
        return cls(
            needles,
            tuple(order),
            solved,
            field_of(data, "orders_tried", where, "int"),
            float(field_of(data, "gamma_mm", where)),
            float(field_of(data, "needle_radius_mm", where)),
            "" if solved else str(field_of(data, "reason", where, "str", optional=True) or ""),
            status=status,
        )


def _rigid_rank(
    maps: list[CFRWMap], order, objective: Objective, radius: float, gamma: float, memo=None
):
    """(needles placed, total length) of an order on the rigid maps, the placed tubes
    tested in closed form. ``memo`` (a dict) keeps each prefix's outcome, so orders that
    share a prefix share its work (k! orders have far fewer distinct prefixes), and the
    directions each placed trajectory blocks in each map (a trajectory recurs in many
    prefixes)."""
    memo = {} if memo is None else memo
    placed: tuple = ()
    total = 0.0
    for n in range(1, len(order) + 1):
        key = tuple(order[:n])
        if key not in memo:
            j = order[n - 1]
            m = maps[j]
            ok = m.feasible.copy()
            for tip, entry in placed:
                # one placed trajectory blocks the same directions of map j in every order
                pair = (j, tip.tobytes(), entry.tobytes())
                if pair not in memo:
                    memo[pair] = _clear_of_placed(m, ((tip, entry),), radius, gamma)
                ok &= memo[pair]
            e = best_direction(_masked(m, ok), objective)
            memo[key] = (
                None if e is None else (placed + ((e.target_mm, e.entry_mm),), total + e.length_mm)
            )
        step = memo[key]
        if step is None:
            return len(placed), total
        placed, total = step
    return len(placed), total


def _clear_of_placed(m: CFRWMap, placed, radius: float, gamma: float) -> np.ndarray:
    """The map's CFRW less the directions whose tube comes closer than gamma to a placed
    needle's tube (axes' distances in closed form)."""
    ok = m.feasible.copy()
    if placed and ok.any():
        idx = np.argwhere(ok)
        tips = np.broadcast_to(m.problem.target_mm, (len(idx), 3))
        ends = m.entry_mm[idx[:, 0], idx[:, 1]]
        clear = np.full(len(idx), np.inf)
        for tip, entry in placed:
            clear = np.minimum(clear, segment_distances(tip, entry, tips, ends))
        ok[idx[:, 0], idx[:, 1]] = clear - 2 * radius >= gamma
    return ok


def _masked(m: CFRWMap, ok: np.ndarray) -> CFRWMap:
    blocked = np.where(ok | (m.blocked != Blocked.FREE), m.blocked, Blocked.PLACED_NEEDLE)
    return replace(m, blocked=blocked)


def plan_needles(
    problem: StraightProblem,
    targets_mm,
    *,
    order=None,
    objective: Objective | str = Objective.MIN_LENGTH,
    deformation=None,
    resolution_deg: float = 1.0,
    head=None,
    body_factory=None,
    keep_going=None,
) -> MultiNeedlePlan:
    """Plan straight needles to several targets, one after another (Fig. 4).

    Parameters
    ----------
    problem : StraightProblem
        Anatomy, needle and limits (its own target is ignored).
    targets_mm : array_like, shape (k, 3)
    order : sequence of int, optional
        A fixed insertion order (target indices); default: searched (module notes).
    objective : Objective or str
        What each trajectory optimises (default the paper's shortest).
    deformation : object, optional
        ``deformation.displacement(points_mm (n, 3), placed) -> (n, 3)`` with ``placed`` the
        needles so far (objects with ``tip_mm``, ``entry_mm``, ``radius_mm``); default:
        rigid anatomy.
    resolution_deg : float
        CFRW grid step.
    head : NeedleHead, optional
        Passed to ``body_factory``.
    body_factory : callable, optional
        ``body_factory(tip_mm, entry_mm, radius_mm) -> DistanceField`` for a placed
        needle; default :class:`~needlekit.anatomy.needle_body.NeedleBody` with the
        paper's head.
    keep_going : callable, optional
        ``keep_going() -> bool``, asked before each CFRW map (a budget); False stops the
        planning, which is then not solved.

    Returns
    -------
    MultiNeedlePlan
    """
    targets = np.asarray(targets_mm, dtype=float).reshape(-1, 3)
    k = len(targets)
    if k == 0 or not np.all(np.isfinite(targets)):
        raise InvalidInputError("targets_mm", "expected one or more finite points (k, 3)")
    obj = Objective(objective)
    radius, gamma = problem.needle.radius_mm, problem.gamma_mm
    if body_factory is None:
        chosen_head = LIU_HEAD if head is None else head

        def body_factory(tip, entry, r):
            return NeedleBody(tip, entry, radius_mm=r, head=chosen_head)

    maps = None
    if order is not None:
        order = tuple(int(i) for i in order)
        if sorted(order) != list(range(k)):
            raise InvalidInputError("order", f"expected a permutation of 0..{k - 1}, got {order}")
        orders_tried = 1
    else:
        maps = []
        for t in targets:
            if keep_going is not None and not keep_going():
                return _stopped(radius, gamma)
            maps.append(cfrw_map(problem.with_target(t), resolution_deg=resolution_deg))
        if k <= EXHAUSTIVE_ORDER_MAX:
            ranked, memo = [], {}
            for perm in itertools.permutations(range(k)):
                n, total = _rigid_rank(maps, perm, obj, radius, gamma, memo)
                ranked.append((-n, total, perm))
            ranked.sort()
            order, orders_tried = ranked[0][2], len(ranked)
        else:
            order, orders_tried = _greedy_order(maps, obj, radius, gamma), 1

    class _Placed:
        def __init__(self, tip, entry, r):
            self.tip_mm, self.entry_mm, self.radius_mm = tip, entry, r

    placed: list = []
    placed_axes: list = []
    bodies: list = []
    records = []
    kept: list = []
    reason = ""
    status = None  # SOLVED or INFEASIBLE, from the needles
    for rank, j in enumerate(order, start=1):
        if keep_going is not None and not keep_going():
            reason = f"the budget ran out before needle {rank}"
            status = Status.APPROXIMATE if records else Status.TIMEOUT
            break
        target = targets[j].copy()
        if deformation is not None and placed:
            target = target + np.asarray(deformation.displacement(target[None], placed))[0]
        if maps is not None and np.array_equal(target, targets[j]):
            base = maps[j]  # the target did not move: the ranking's map of the anatomy
        else:
            base = cfrw_map(problem.with_target(target), resolution_deg=resolution_deg)
        # the anatomy's map less what the placed needles block (CFRWMap.with_obstacles)
        m = base.with_obstacles(*bodies)
        kept.append(m)
        e, cert, why = certified_best(
            m, obj, problem=problem.with_target(target), placed=tuple(placed_axes),
            bodies=tuple(bodies),
        )  # fmt: skip
        needle_clear = np.inf if cert is None else cert.needle_clearance_mm
        records.append(
            NeedleRecord(rank, j, targets[j].copy(), target, e, needle_clear, m.counts())
        )
        if e is None:
            reason = f"needle {rank} (target {j}): no trajectory in its CFRW; " + (
                why or m.blocking_summary()
            )
            break
        # the needle as recorded (rounded) is the obstacle the next ones see and verify builds
        placed.append(_Placed(e.target_mm, e.entry_mm, radius))
        placed_axes.append((e.target_mm, e.entry_mm))
        bodies.append(body_factory(e.target_mm, e.entry_mm, radius))
    return MultiNeedlePlan(
        tuple(records),
        tuple(order),
        len(records) == k and all(r.entry is not None for r in records),
        orders_tried,
        gamma,
        radius,
        reason,
        tuple(kept),
        status,
    )


def _stopped(radius: float, gamma: float) -> MultiNeedlePlan:
    """A plan the budget stopped before any needle was placed: a timeout."""
    reason = "the budget ran out while mapping"
    return MultiNeedlePlan((), (), False, 0, gamma, radius, reason, status=Status.TIMEOUT)


def _greedy_order(maps, obj, radius, gamma) -> tuple:
    left = list(range(len(maps)))
    order: list[int] = []
    placed: list = []
    while left:
        sizes = []
        for j in left:
            ok = _clear_of_placed(maps[j], placed, radius, gamma)
            sizes.append((int(ok.sum()), j, ok))
        _, j, ok = min(sizes, key=lambda s: (s[0], s[1]))
        order.append(j)
        left.remove(j)
        e = best_direction(_masked(maps[j], ok), obj)
        if e is not None:
            placed.append((e.target_mm, e.entry_mm))
    return tuple(order)
