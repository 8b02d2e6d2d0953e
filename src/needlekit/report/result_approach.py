"""Report part of an approach analysis (``approach.json`` of ``needlekit approach``): the
page ``approach --report`` writes, drawn again from the file and its scenario.

The file keeps every skin triangle's answer, not the meshes: the skin and the obstacles
are meshed again from the scenario as the command meshed them (its ``max_cells``, the
needle's reach around the target), and must give the file's triangles (their number and
centres) before the file's answers colour them.
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile
from needlekit.planning.straight.approach import ApproachAnalysis, approach_meshes
from needlekit.report.approach_report import approach_sections, approach_title
from needlekit.report.result_parts import ReportPart

__all__: list[str] = []

#: The command's default ``--max-cells``: a record written before it kept the value was
#: meshed with it unless the flag was given (then its triangles tell).
_DEFAULT_MAX_CELLS = 200
#: How far a skin triangle's centre meshed again may lie from the file's (mm): the file
#: rounds them to 1e-4 mm.
_CENTRE_TOLERANCE_MM = 1e-3


def _another(rf: ResultFile, what: str) -> InvalidInputError:
    return InvalidInputError(
        str(rf.path),
        f"{what}: it was made from another scenario (give that one with --scenario)",
    )


def _approach_part(rf: ResultFile, load) -> ReportPart:
    d = rf.data
    a = ApproachAnalysis.from_dict(d, rf.path.name)
    sc = load(rf.scenario)
    multi, _ = load.multi_problem(sc)
    p = multi.problem
    for key, mine in (("gamma_mm", p.gamma_mm), ("needle_radius_mm", p.needle.radius_mm)):
        theirs = a.settings[key]
        if not np.isclose(theirs, mine, rtol=0, atol=1e-9):
            raise _another(rf, f"{key} is {theirs:g}, the scenario {rf.scenario} gives {mine:g}")
    targets = np.asarray(multi.targets_mm, float).reshape(-1, 3)
    if not np.any(np.all(np.isclose(targets, a.target_mm, rtol=0, atol=1e-6), axis=1)):
        raise _another(rf, f"its target is not one of the targets of {rf.scenario}")
    max_cells = d.get("max_cells", _DEFAULT_MAX_CELLS)
    skin, obstacles = approach_meshes(p, a.target_mm, max_cells=int(max_cells))
    file_obstacles = d.get("obstacles") or {}
    counts = {name: int(len(m.faces)) for name, m in obstacles.items()}
    same = len(skin.faces) == len(a.areas_mm2) and (not file_obstacles or file_obstacles == counts)
    if same:
        off = np.max(np.abs(np.asarray(skin.triangles_center) - a.centres_mm), initial=0.0)
        same = off <= _CENTRE_TOLERANCE_MM
    if not same:
        how = "" if "max_cells" in d else " (the record keeps no max_cells: meshed with 200)"
        raise _another(
            rf,
            f"{rf.scenario} meshed at max_cells {max_cells}{how} gives {len(skin.faces)} skin "
            f"triangles and obstacles {counts}, not the file's {len(a.areas_mm2)} and "
            f"{file_obstacles}, or other centres",
        )
    title = approach_title(sc, rf.scenario)
    best = a.shortest()
    line = "no accessible triangle" if best is None else f"shortest {best['length_mm']:.2f} mm"
    return ReportPart(
        rf,
        title,
        approach_sections(a, skin, obstacles, title=title),
        f"{len(a.areas_mm2)} skin triangles: score {a.score_paa:.4f} by PAA's line test, "
        f"{a.score:.4f} by needlekit's criteria, {line}; the meshes made again from the "
        "scenario match the file's",
    )
