"""The true tip's path as an insertion records it (:class:`TipPath`): what the executed
path's clearance is certified on (:func:`needlekit.execute.record.path_record`)."""

from __future__ import annotations

import numpy as np

__all__ = ["TipPath"]


class TipPath:
    """The true tip's path as a run records it: points every ``record_mm`` of insertion
    and at the end, and beside them, when the truth maps its tissue back (``to_rest``),
    each point in the anatomy at rest, mapped when it was recorded. Under breathing the
    points are the tip in the tissue: the world point less the displacement, or, for a
    truth that breathes its organ itself (``breathe``), the world point, its ``to_rest``
    the tissue's."""

    def __init__(self, needle, record_mm: float) -> None:
        self.needle = needle
        self.to_rest = getattr(needle, "to_rest", None)  # the truth's optional capabilities
        self.breathes = self.to_rest is not None and hasattr(needle, "breathe")
        self.record_mm = record_mm
        self.points: list[np.ndarray] = []
        self.rest: list[np.ndarray] = []
        self.last = 0.0
        self._add(needle.pose[:3, 3].copy())

    def _add(self, p: np.ndarray, q=None) -> None:
        self.points.append(p)
        if self.to_rest is not None:
            self.rest.append(np.asarray(self.to_rest(p[None]), dtype=np.float64)[0] if q is None else q)

    def tissue_point(self) -> np.ndarray:
        """The last recorded point in the tissue (at rest when the truth maps it).

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.rest[-1] if self.to_rest is not None else self.points[-1]

    def _at(self, offset) -> np.ndarray:
        p = self.needle.pose[:3, 3].copy()
        return p if offset is None or self.breathes else p - offset

    def record(self, offset=None) -> bool:
        """Record the tip if it has gone far enough.

        Parameters
        ----------
        offset : ndarray, shape (3,), optional
            The tissue's displacement (breathing): the tip then moves in the tissue while
            it is not inserted, and is recorded by how far it went there.

        Returns
        -------
        bool
            Whether it was recorded.
        """
        if offset is None:
            if self.needle.inserted_mm - self.last >= self.record_mm - 1e-9:
                self._add(self._at(None))
                self.last = self.needle.inserted_mm
                return True
            return False
        p = self._at(offset)
        if self.breathes:
            q = np.asarray(self.to_rest(p[None]), dtype=np.float64)[0]
            if np.linalg.norm(q - self.rest[-1]) >= self.record_mm - 1e-9:
                self._add(p, q)
                return True
            return False
        if np.linalg.norm(p - self.points[-1]) >= self.record_mm - 1e-9:
            self._add(p)
            return True
        return False

    def end(self, offset=0.0) -> None:
        """Record the tip where the insertion stopped.

        Parameters
        ----------
        offset : float or ndarray, shape (3,)
            The tissue's displacement then (breathing), else 0.

        Returns
        -------
        None
        """
        self._add(self._at(offset))

    def rest_array(self) -> np.ndarray | None:
        """The recorded points at rest, when the truth maps its tissue back.

        Returns
        -------
        ndarray, shape (k, 3), or None
        """
        return None if self.to_rest is None else np.array(self.rest)

    def final_error(self, goal) -> float:
        """The final error: in the world to the target where it is now when the truth
        says (``target_mm()``), else at rest to the scenario's goal when the truth maps its
        tissue back, else in the world to the goal.

        Parameters
        ----------
        goal : ndarray, shape (3,)

        Returns
        -------
        float
        """
        target = getattr(self.needle, "target_mm", None)
        if target is not None:
            return float(np.linalg.norm(self.points[-1] - np.asarray(target(), dtype=np.float64)))
        if self.to_rest is not None:
            return float(np.linalg.norm(self.rest[-1] - goal))
        return float(np.linalg.norm(self.points[-1] - goal))
