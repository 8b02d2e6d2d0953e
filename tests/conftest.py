"""Test-session set-up shared by every test folder.

- The prepared-anatomy cache: a temporary one for the whole session.
- The Med-RAD data (real patients, CC BY-NC-SA 4.0): tests that need it are marked
  ``realdata``; they skip, saying why, when it is absent (it is read from
  ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``, never copied here). The fixtures
  load each case once per test process.
"""

import os
import shutil
import tempfile

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.io.medrad import MEDRAD_ENV, load_medrad, medrad_root

_CACHE_ENV = "NEEDLEKIT_CACHE_DIR"
_saved: dict = {}


def pytest_configure(config):
    # Tests never read or write the user's prepared-anatomy cache: the whole session (and
    # the commands it starts) uses a temporary one, removed at the end. xdist workers
    # inherit the controller's (set before they start), so a patient is prepared once per
    # session, not once per worker: entries are written atomically (io.anatomy_cache).
    if hasattr(config, "workerinput") and os.environ.get(_CACHE_ENV):
        return
    _saved["env"] = os.environ.get(_CACHE_ENV)
    _saved["dir"] = tempfile.mkdtemp(prefix="needlekit-test-cache-")
    os.environ[_CACHE_ENV] = _saved["dir"]


def pytest_unconfigure(config):
    if "dir" not in _saved:
        return
    shutil.rmtree(_saved.pop("dir"), ignore_errors=True)
    env = _saved.pop("env")
    if env is None:
        os.environ.pop(_CACHE_ENV, None)
    else:
        os.environ[_CACHE_ENV] = env


def _medrad_root():
    try:
        return medrad_root()
    except InvalidInputError:
        return None


MEDRAD_ROOT = _medrad_root()
MEDRAD_MISSING = f"Med-RAD data not found: set {MEDRAD_ENV} or place it at ../shared/data/med-rad"


def pytest_collection_modifyitems(config, items):
    # Modules holding slow tests first: `make test` hands whole modules to its two workers
    # (--dist loadscope) in this order, so the long ones start at once and the many short
    # ones fill in behind them instead of one long module running alone at the end. The
    # order within a module, and among the rest, stays as collected.
    slow = {item.nodeid.split("::")[0] for item in items if "slow" in item.keywords}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow)
    if MEDRAD_ROOT is not None:
        return
    skip = pytest.mark.skip(reason=MEDRAD_MISSING)
    for item in items:
        if "realdata" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def medrad_dir():
    """The Med-RAD folder (tests using it must be marked ``realdata``)."""
    if MEDRAD_ROOT is None:
        pytest.skip(MEDRAD_MISSING)
    return MEDRAD_ROOT


@pytest.fixture(scope="session")
def medrad_lung1(medrad_dir):
    """Med-RAD lung patient 1, loaded once per test process."""
    return load_medrad("lung", 1, medrad_dir)


# -- the exact oracle of plans on phantoms -----------------------------------------------
# A phantom's scene bakes its trees into voxel grids (with a stated error bound); its
# ``exact_fields`` keep the closed forms. Plans on a phantom are re-checked against those:
# the independent check of a plan must not share the planner's field.

#: Arc-length spacing (mm) of the points at which the oracle measures a plan's clearance.
EXACT_CHECK_SPACING_MM = 0.1

_exact_fields: dict[int, tuple] = {}


def exact_obstacle_field(phantom, extra=()):
    """The phantom's obstacle field from its exact structures (same names and roles as its
    scene), with ``extra`` structures a scenario adds (exact themselves: closed forms),
    built once per phantom and extras."""
    from needlekit.anatomy.scene import Scene, Structure

    key = (id(phantom), tuple(s.name for s in extra))
    if key not in _exact_fields:
        structures = [
            Structure(s.name, s.role, phantom.exact_fields[s.name])
            for s in phantom.scene.structures
        ]
        # the phantom is kept beside its field so that its id stays its own
        field = Scene([*structures, *extra]).obstacle_field(0.0)
        _exact_fields[key] = (phantom, field)
    return _exact_fields[key][1]


def check_exact_clearance(phantom, problem, plan, certified_clearance_mm=None) -> float:
    """Re-check a plan on a phantom with exact distances; returns its exact clearance (mm,
    from the needle's surface, outside the start exclusion ball, at points 0.1 mm apart).

    Asserts that it is at least the problem's safety margin and at least the
    ``certified_clearance_mm`` the planner reported (which claims to be a lower bound).
    """
    scene_roles = [(s.name, s.role) for s in problem.scene.structures]
    base = [(s.name, s.role) for s in phantom.scene.structures]
    assert scene_roles[: len(base)] == base
    extra = problem.scene.structures[len(base) :]  # added by the scenario: closed forms
    assert all(s.field.error_bound_mm == 0.0 for s in extra)
    field = exact_obstacle_field(phantom, tuple(extra))
    points = plan.points_mm(EXACT_CHECK_SPACING_MM)
    start = plan.start_pose[:3, 3]
    far = np.linalg.norm(points - start, axis=1) >= problem.start_exclusion_mm
    assert far.any(), "the whole plan lies inside the start exclusion"
    radius = 0.5 * problem.needle_diameter_mm
    clearance = float(field.signed_distance(points[far]).min()) - radius
    tol = float(field.error_bound_mm)
    assert clearance >= problem.safety_margin_mm - tol, (
        f"exact clearance {clearance:.6f} mm below the safety margin "
        f"{problem.safety_margin_mm:g} mm"
    )
    if certified_clearance_mm is not None:
        assert clearance >= float(certified_clearance_mm) - tol, (
            f"exact clearance {clearance:.6f} mm below the certified "
            f"{float(certified_clearance_mm):.6f} mm"
        )
    return clearance


@pytest.fixture(scope="session")
def exact_clearance():
    """:func:`check_exact_clearance`, for tests on phantoms (conftest modules are not
    importable under ``--import-mode=importlib``)."""
    return check_exact_clearance
