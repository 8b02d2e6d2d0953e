"""Where the Med-RAD data lives: the folder, its organs and patients (no anatomy loaded).

Split from :mod:`needlekit.io.medrad` so that the command line can refuse a wrong folder or
patient before it loads numpy's heavier neighbours (numba, scipy); :mod:`needlekit.io.medrad`
re-exports these names.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path

from needlekit.errors import InvalidInputError

__all__ = ["MEDRAD_ENV", "chosen_patients", "list_patients", "medrad_root", "patient_folder"]

#: Environment variable naming the Med-RAD folder.
MEDRAD_ENV = "NEEDLEKIT_MEDRAD"

_ORGANS = {"lung": Path("Lungs") / "TumorTargetEnvironments", "liver": Path("Liver")}


def _repo_candidates() -> list[Path]:
    here = Path(__file__).resolve()
    # src/needlekit/io/medrad.py -> repository root is parents[3]
    roots = [Path.cwd(), here.parents[3]] if len(here.parents) > 3 else [Path.cwd()]
    return [r.parent / "shared" / "data" / "med-rad" for r in roots]


def medrad_root(root: str | os.PathLike | None = None) -> Path:
    """The Med-RAD folder: ``root``, else ``$NEEDLEKIT_MEDRAD``, else ``../shared/data/med-rad``.

    Parameters
    ----------
    root : path-like, optional

    Returns
    -------
    Path

    Raises
    ------
    InvalidInputError
        No such folder (the message says where it looked).
    """
    if root is not None:
        p = Path(root)
        if not p.is_dir():
            raise InvalidInputError("root", f"Med-RAD folder {p} does not exist")
        return p
    env = os.environ.get(MEDRAD_ENV)
    if env:
        p = Path(env)
        if not p.is_dir():
            raise InvalidInputError(MEDRAD_ENV, f"Med-RAD folder {p} does not exist")
        return p
    for p in _repo_candidates():
        if p.is_dir():
            return p
    looked = ", ".join(str(p) for p in _repo_candidates())
    raise InvalidInputError(
        "med-rad", f"data not found (looked in {looked}); set {MEDRAD_ENV} or pass root"
    )


def _organ(organ: str) -> str:
    key = str(organ).lower().rstrip("s")
    if key not in _ORGANS:
        raise InvalidInputError("organ", f"expected 'lung' or 'liver', got {organ!r}")
    return key


def list_patients(organ: str, root: str | os.PathLike | None = None) -> list[int]:
    """Patient numbers available for an organ.

    Parameters
    ----------
    organ : {"lung", "liver"}
    root : path-like, optional

    Returns
    -------
    list of int
    """
    folder = medrad_root(root) / _ORGANS[_organ(organ)]
    found = []
    for p in folder.glob("Patient*") if folder.is_dir() else []:
        m = re.fullmatch(r"Patient(\d+)", p.name)
        if m and p.is_dir():
            found.append(int(m.group(1)))
    return sorted(found)


def patient_folder(organ: str, patient: int, root=None, *, flag: str = "--medrad") -> Path:
    """A patient's folder, which must exist.

    Parameters
    ----------
    organ : {"lung", "liver"}
    patient : int
    root : path-like, optional
        Med-RAD folder (default: :func:`medrad_root`'s).
    flag : str
        Named in the error.

    Returns
    -------
    Path

    Raises
    ------
    InvalidInputError
        No Med-RAD folder, or no such patient in it.
    """
    key = _organ(organ)
    folder = medrad_root(root) / _ORGANS[key] / f"Patient{int(patient)}"
    if not folder.is_dir():
        raise InvalidInputError(flag, f"no Med-RAD {key} patient {int(patient)} at {folder}")
    return folder


def chosen_patients(
    organ: str,
    root=None,
    patients: Sequence[int] | None = None,
    *,
    root_flag: str = "--medrad",
    patients_flag: str = "--patients",
) -> tuple[Path, list[int]]:
    """The Med-RAD folder and the patients of an organ a study runs on.

    Parameters
    ----------
    organ : {"lung", "liver"}
    root : path-like, optional
    patients : sequence of int, optional
        Default: every ``Patient*`` folder.
    root_flag, patients_flag : str
        Named in the errors.

    Returns
    -------
    (Path, list of int)

    Raises
    ------
    InvalidInputError
        No patients under the folder, or a patient that is not there.
    """
    key = _organ(organ)
    where = medrad_root(root)
    found = list_patients(key, where)
    if not found:
        raise InvalidInputError(root_flag, f"no Med-RAD {key} patients under {where}")
    chosen = list(found if patients is None else patients)
    missing = sorted(set(chosen) - set(found))
    if missing:
        raise InvalidInputError(
            patients_flag, f"no patient {missing} under {where} (there: {found})"
        )
    return where, chosen
