"""The UNC reference planner's RCS* app: its input files, running it, reading its output.

``needlekit bench steerable --reference-app PATH`` runs, for every Med-RAD lung case
(patient x start x r_min), the authors' C++ app (``rcs_star`` of UNC-Robotics'
steerable-needle-planner, built from its public source) and needlekit's ``rcs_star`` in
the same process, one after the other, the order alternating from case to case (app
first on even cases, needlekit first on odd ones), with ``/proc/loadavg`` recorded
before every run. Everything needlekit contributes goes through its public API
(:func:`needlekit.io.medrad.load_medrad`, ``MedradCase.voxel_obstacles``, the starts and
the target), so the comparison keeps working as the internals change; the standalone
tool in ``../shared/tools/unc-reference/`` stays the yardstick it must agree with. The
comparison itself is :mod:`needlekit.benchmarks.reference_comparison`.

The app's inputs (one folder per case, run from its ``bin/``)::

    data/input/obstacles.txt             the patient's obstacle file (a link; written once)
    data/input/start_and_goal_poses.txt  "x y z qw qx qy qz" of the start, then the target
    data/input/needle_parameters.txt     "r_min diameter l_max angle_deg"
    data/input/costs.txt                 empty (the path-length cost ignores it)
    data/output/                         the app's plans
    run.log                              the app's output without its progress stream

The obstacle file holds the 4x4 ijk -> RAS affine of the crop (4 lines), the crop size
``ni nj nk`` and one ``i j k`` line per obstacle voxel in crop indices. The crop is the box
around the starts and the target +- :data:`CROP_MARGIN_MM`; the app counts every point
outside it as a collision. The obstacle voxels are needlekit's (everything that is not
free space); only those within :data:`SHELL_MM` of free space are written, which keeps the
file small (the region outside the lung is most of the crop) and changes no collision
answer the search can see: a needle point within ``SHELL_MM - r`` of free space has the
same obstacle voxels within its radius ``r``, and the search reaches nothing deeper
without crossing the shell.

The app is run as ``rcs_star 0 0 1`` (no goal orientation, single thread, seed 1) with
its stock 1 s budget (``ProblemConfig::timeout``), which ends early when the queue is
exhausted; needlekit gets the same 1 s. The app loads the obstacle file and builds its
KD-tree in every run (tens of seconds on lung 3): its "solve time" excludes that, and so
does nothing here count it.
"""

from __future__ import annotations

import os
import re
import resource
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial.transform import Rotation

from needlekit.errors import InvalidInputError

__all__ = [
    "APP_ARGUMENTS",
    "COST_AGREEMENT_MM",
    "CROP_MARGIN_MM",
    "REFERENCE_BUDGET_S",
    "SHELL_MM",
    "check_reference_app",
    "parse_app_log",
    "run_reference_app",
    "write_case_folder",
    "write_obstacle_file",
]

#: The stock app's budget (``ProblemConfig::timeout``, 1000 ms); it cannot be changed
#: without rebuilding the app, so needlekit gets the same.
REFERENCE_BUDGET_S = 1.0
#: ``rcs_star 0 0 1``: no goal orientation, single thread, seed 1.
APP_ARGUMENTS = ("0", "0", "1")
#: The app prints no "exhausted" line: a solve time below this fraction of the budget
#: means its queue ran empty (the search finished) rather than the budget running out.
EXHAUSTED_FRACTION = 0.95
#: Costs within this many mm agree (the app prints 6 significant digits).
COST_AGREEMENT_MM = 1e-3
#: The crop around the starts and the target (mm), as the shared yardstick's.
CROP_MARGIN_MM = 30.0
#: Obstacle voxels farther than this from free space (mm) are left out of the file.
SHELL_MM = 3.0
#: A whole app run (loading included) that takes longer than this has failed.
APP_TIMEOUT_S = 1800.0

#: The app's pre-check refusals (``needle_validator.h``) and needlekit's verdict for each.
REFUSALS = {
    "Start point is outside image range": "invalid",
    "Goal point is outside image range": "invalid",
    "Start point is in collision": "invalid",
    "Goal point is in collision": "invalid",
    "Exceed maximum insertion distance": "infeasible",
    "Goal point not in FRS": "infeasible",
    "Reachable workspace is not connected to the goal": "infeasible",
    "Start point not in BRS": "infeasible",
    "Mission impossible": "infeasible",
}

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf|nan"
_SOLVE_TIME = re.compile(rf"solve time ({_NUMBER}) seconds")
_ITERATIONS = re.compile(r"iterations: (\d+)")
_FOUND = re.compile(rf"found solution with cost ({_NUMBER})")
_TIME_COST = re.compile(rf"\s*({_NUMBER}), ({_NUMBER})\s*")
_NEEDS_R = re.compile(rf"need rad to be ({_NUMBER})")
_PROGRESS = "Loaded obstacle points: "
_CHUNK = 1 << 20
_MAX_LINE = 1 << 16


def check_reference_app(path: str | os.PathLike) -> Path:
    """The app's path, checked: an existing, executable regular file.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    Path

    Raises
    ------
    InvalidInputError
        Naming ``--reference-app``.
    """
    p = Path(path)
    if not p.exists():
        raise InvalidInputError("--reference-app", f"{p}: not found")
    if not p.is_file():
        raise InvalidInputError(
            "--reference-app", f"{p}: is not a file (expected the built rcs_star)"
        )
    if not os.access(p, os.X_OK):
        raise InvalidInputError("--reference-app", f"{p}: is not executable")
    return p.resolve()


# -- the app's input files ----------------------------------------------------------------


def write_obstacle_file(
    path: str | os.PathLike,
    occupancy: np.ndarray,
    affine: np.ndarray,
    points_mm: np.ndarray,
    *,
    margin_mm: float = CROP_MARGIN_MM,
    shell_mm: float = SHELL_MM,
) -> dict[str, Any]:
    """Write the app's obstacle file for one patient.

    Parameters
    ----------
    path : path-like
        Written atomically (a temporary file beside it, then renamed).
    occupancy : ndarray of bool, shape (i, j, k)
        Obstacle voxels (True), e.g. ``MedradCase.voxel_obstacles(...).occupancy``.
    affine : ndarray, shape (4, 4)
        Voxel index -> RAS (mm) of ``occupancy``.
    points_mm : ndarray, shape (n, 3)
        The starts and the target (RAS mm): the crop is their bounding box +- ``margin_mm``.
    margin_mm : float
    shell_mm : float
        Obstacle voxels farther than this from the nearest free voxel are left out.

    Returns
    -------
    dict
        ``crop_lo``, ``crop_hi`` (voxel indices, ``hi`` exclusive), ``crop_size``,
        ``margin_mm``, ``shell_mm``, ``obstacle_voxels`` (in the crop) and
        ``written_voxels`` (in the file).
    """
    occ = np.asarray(occupancy, dtype=bool)
    a = np.asarray(affine, dtype=float)
    shape = np.asarray(occ.shape)
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    lo_mm, hi_mm = pts.min(axis=0) - margin_mm, pts.max(axis=0) + margin_mm
    corners = np.array([[x, y, z] for x in (lo_mm[0], hi_mm[0])
                        for y in (lo_mm[1], hi_mm[1]) for z in (lo_mm[2], hi_mm[2])])  # fmt: skip
    ijk = (corners - a[:3, 3]) @ np.linalg.inv(a[:3, :3]).T
    lo = np.clip(np.floor(ijk.min(axis=0)).astype(int), 0, shape)
    hi = np.clip(np.ceil(ijk.max(axis=0)).astype(int) + 1, 0, shape)
    if np.any(hi <= lo):
        raise InvalidInputError("points_mm", "the crop around the starts and target is empty")
    # distances to free space need the grid a little beyond the crop
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    pad = np.ceil(shell_mm / spacing).astype(int) + 1
    big_lo, big_hi = np.maximum(lo - pad, 0), np.minimum(hi + pad, shape)
    big = occ[tuple(slice(int(s), int(e)) for s, e in zip(big_lo, big_hi, strict=True))]
    depth = ndimage.distance_transform_edt(big, sampling=spacing)
    inner = tuple(slice(int(s), int(e)) for s, e in zip(lo - big_lo, hi - big_lo, strict=True))
    crop_occ = big[inner]
    keep = crop_occ & (depth[inner] <= shell_mm)
    crop_affine = a.copy()
    crop_affine[:3, 3] = a[:3, :3] @ lo + a[:3, 3]
    out = Path(path)
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "w", encoding="ascii") as fh:
        for row in crop_affine:
            fh.write(" ".join(repr(float(v)) for v in row) + "\n")
        fh.write(" ".join(str(int(v)) for v in hi - lo) + "\n")
        np.savetxt(fh, np.argwhere(keep), fmt="%d")
    tmp.replace(out)
    return {
        "crop_lo": lo.tolist(),
        "crop_hi": hi.tolist(),
        "crop_size": (hi - lo).tolist(),
        "margin_mm": float(margin_mm),
        "shell_mm": float(shell_mm),
        "obstacle_voxels": int(crop_occ.sum()),
        "written_voxels": int(keep.sum()),
    }


def write_case_folder(
    folder: str | os.PathLike,
    obstacle_file: str | os.PathLike,
    world_T_tip: np.ndarray,
    target_mm: np.ndarray,
    needle: dict[str, float],
) -> Path:
    """Write one case's folder for the app (see the module's description).

    Parameters
    ----------
    folder : path-like
        Created if needed; its ``data/output`` is emptied.
    obstacle_file : path-like
        The patient's obstacle file (:func:`write_obstacle_file`), linked (copied where
        links are not possible).
    world_T_tip : ndarray, shape (4, 4)
        The start pose (RAS mm, z = insertion direction).
    target_mm : ndarray, shape (3,)
    needle : dict
        ``r_min_mm``, ``needle_diameter_mm``, ``max_length_mm``, ``max_heading_change_deg``.

    Returns
    -------
    Path
        The folder.
    """
    case = Path(folder)
    inp, outp = case / "data" / "input", case / "data" / "output"
    for d in (inp, outp, case / "bin"):
        d.mkdir(parents=True, exist_ok=True)
    for f in outp.iterdir():
        if f.is_file() or f.is_symlink():
            f.unlink()
    link = inp / "obstacles.txt"
    if link.is_symlink() or link.exists():
        link.unlink()
    try:
        link.symlink_to(os.path.relpath(Path(obstacle_file).resolve(), inp.resolve()))
    except OSError:
        link.write_bytes(Path(obstacle_file).read_bytes())
    pose = np.asarray(world_T_tip, dtype=float)
    qx, qy, qz, qw = Rotation.from_matrix(pose[:3, :3]).as_quat()
    start = [*pose[:3, 3], qw, qx, qy, qz]
    goal = [float(v) for v in np.asarray(target_mm, dtype=float).reshape(3)]
    (inp / "start_and_goal_poses.txt").write_text(
        " ".join(repr(float(v)) for v in start) + "\n" + " ".join(map(repr, goal)) + " 1 0 0 0\n"
    )
    (inp / "needle_parameters.txt").write_text(
        f"{needle['r_min_mm']:g} {needle['needle_diameter_mm']:g} "
        f"{needle['max_length_mm']:g} {needle['max_heading_change_deg']:g}\n"
    )
    (inp / "costs.txt").write_text("")
    return case


# -- running the app and reading what it prints -------------------------------------------


def _lines(path: Path) -> Iterator[str]:
    """The lines of a log split at ``\\n`` and ``\\r``, read in chunks (the app's progress
    stream is one line of tens of MB); a line longer than 64 KiB is cut."""
    carry = ""
    with open(path, encoding="utf-8", errors="replace", newline="") as fh:
        while chunk := fh.read(_CHUNK):
            parts = re.split(r"[\r\n]", carry + chunk)
            carry = parts.pop()[-_MAX_LINE:]
            yield from parts
    if carry:
        yield carry


def parse_app_log(lines, budget_s: float = REFERENCE_BUDGET_S) -> dict[str, Any]:
    """What one app run printed.

    Parameters
    ----------
    lines : iterable of str
        The output's lines (progress lines ``Loaded obstacle points: N`` are counted, not kept).
    budget_s : float
        The app's budget (to tell an exhausted queue from a used-up budget).

    Returns
    -------
    dict
        ``status`` (``certified``, ``solved (budget)``, ``no plan (exhausted)``, ``no plan
        (budget)``, ``refused`` or ``failed``), ``verdict`` (in needlekit's terms:
        ``certified``, ``solved``, ``infeasible``, ``no plan``, ``invalid`` or ``failed``),
        ``reason`` (a refusal's message), ``needs_r_min_mm`` (FRS refusal), ``solve_s``,
        ``exhausted``, ``iterations``, ``solutions`` (``[time_s, cost_mm]`` of each
        improvement, the app's ``resultWithTime``), ``found_costs_mm``, ``cost_mm`` (the
        best), ``first_solution_s``, ``obstacle_points`` and ``kept`` (the other lines).
    """
    out: dict[str, Any] = {"solutions": [], "found_costs_mm": [], "kept": []}
    solve_s = iterations = points = reason = needs = None
    for line in lines:
        if line.startswith(_PROGRESS):
            points = line[len(_PROGRESS) :].strip() or points
            continue
        out["kept"].append(line)
        if m := _SOLVE_TIME.search(line):
            solve_s = float(m.group(1))
        elif m := _ITERATIONS.search(line):
            iterations = int(m.group(1))
        elif m := _FOUND.search(line):
            out["found_costs_mm"].append(float(m.group(1)))
        elif m := _TIME_COST.fullmatch(line):
            out["solutions"].append([float(m.group(1)), float(m.group(2))])
        elif reason is None:
            reason = next((msg for msg in REFUSALS if line.startswith(msg)), None)
            if reason is not None and (m := _NEEDS_R.search(line)):
                needs = float(m.group(1))
    sol = out["solutions"]
    exhausted = solve_s is not None and solve_s < EXHAUSTED_FRACTION * budget_s
    if solve_s is None:
        status = "refused" if reason is not None else "failed"
        verdict = REFUSALS[reason] if reason is not None else "failed"
    elif sol:
        status, verdict = ("certified",) * 2 if exhausted else ("solved (budget)", "solved")
    else:
        status = "no plan (exhausted)" if exhausted else "no plan (budget)"
        verdict = "infeasible" if exhausted else "no plan"
    out.update(
        status=status,
        verdict=verdict,
        reason=reason,
        needs_r_min_mm=needs,
        solve_s=solve_s,
        exhausted=exhausted,
        iterations=iterations,
        cost_mm=sol[-1][1] if sol else None,
        first_solution_s=sol[0][0] if sol else None,
        obstacle_points=int(points) if points and points.isdigit() else None,
    )
    return out


def _no_core_dumps() -> None:  # the app aborts (uncaught exception) on a refused problem
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def run_reference_app(
    app: str | os.PathLike, case_folder: str | os.PathLike, budget_s: float = REFERENCE_BUDGET_S
) -> dict[str, Any]:
    """Run the app once in a case folder (from its ``bin/``) and read what it printed.

    Its output goes to a file (never into memory whole), then ``run.log`` keeps it without
    the progress stream.

    Parameters
    ----------
    app : path-like
        The built ``rcs_star`` (:func:`check_reference_app`).
    case_folder : path-like
        Written by :func:`write_case_folder`.
    budget_s : float

    Returns
    -------
    dict
        :func:`parse_app_log`'s figures (without ``kept``), ``returncode``,
        ``process_wall_s`` (loading and pre-checks included) and ``log``.
    """
    case = Path(case_folder)
    raw, log = case / "run.raw.log", case / "run.log"
    for f in (case / "data" / "output").iterdir():
        if f.is_file():
            f.unlink()
    t0 = time.perf_counter()
    with open(raw, "wb") as fh:
        try:
            proc = subprocess.run(
                [str(app), *APP_ARGUMENTS],
                cwd=case / "bin",
                stdout=fh,
                stderr=subprocess.STDOUT,
                preexec_fn=_no_core_dumps,
                timeout=APP_TIMEOUT_S,
                check=False,
            )
            code = proc.returncode
        except subprocess.TimeoutExpired:
            code = None
    wall = time.perf_counter() - t0
    res = parse_app_log(_lines(raw), budget_s)
    log.write_text("\n".join(res.pop("kept")) + "\n", encoding="utf-8")
    raw.unlink()
    if code is None:
        res.update(status="failed", verdict="failed", reason=f"timeout after {APP_TIMEOUT_S:g} s")
    return {**res, "returncode": code, "process_wall_s": wall, "log": str(log)}
