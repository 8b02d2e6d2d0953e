"""Test-session set-up shared by every test folder.

- The prepared-anatomy cache: a temporary one for the whole session.
- Runs several test modules read (a plan and its execution, say): made once per session,
  whichever xdist worker needs one first, and read by the others (:func:`shared_run`).
- The Med-RAD data (real patients, CC BY-NC-SA 4.0): tests that need it are marked
  ``realdata``; they skip, saying why, when it is absent (it is read from
  ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``, never copied here). The fixtures
  load each case once per test process.
"""

import fcntl
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.io.medrad import MEDRAD_ENV, load_medrad, medrad_root

_CACHE_ENV = "NEEDLEKIT_CACHE_DIR"
_KEY_ENV = "NEEDLEKIT_CACHE_KEY_FILE"
#: The folder of the session's shared runs (set by the controller, read by its workers).
_SHARED_ENV = "NEEDLEKIT_TEST_SHARED_RUNS"
_saved: dict = {}


def pytest_configure(config):
    # Tests never read or write the user's prepared-anatomy cache: the whole session (and
    # the commands it starts) uses a temporary one, removed at the end. xdist workers
    # inherit the controller's (set before they start), so a patient is prepared once per
    # session, not once per worker: entries are written atomically (io.anatomy_cache).
    if hasattr(config, "workerinput") and os.environ.get(_CACHE_ENV):
        return
    _saved["env"] = os.environ.get(_CACHE_ENV)
    _saved["key_env"] = os.environ.get(_KEY_ENV)
    _saved["dir"] = tempfile.mkdtemp(prefix="needlekit-test-cache-")
    os.environ[_CACHE_ENV] = _saved["dir"]
    # and the key that signs it: the session's own, never the user's
    _saved["key_dir"] = tempfile.mkdtemp(prefix="needlekit-test-key-")
    os.environ[_KEY_ENV] = os.path.join(_saved["key_dir"], "cache.key")
    _saved["shared_env"] = os.environ.get(_SHARED_ENV)
    _saved["shared_dir"] = tempfile.mkdtemp(prefix="needlekit-test-runs-")
    os.environ[_SHARED_ENV] = _saved["shared_dir"]


def pytest_unconfigure(config):
    if "dir" not in _saved:
        return
    shutil.rmtree(_saved.pop("dir"), ignore_errors=True)
    shutil.rmtree(_saved.pop("key_dir"), ignore_errors=True)
    shutil.rmtree(_saved.pop("shared_dir"), ignore_errors=True)
    for name, saved in ((_CACHE_ENV, _saved.pop("env")), (_KEY_ENV, _saved.pop("key_env")),
                        (_SHARED_ENV, _saved.pop("shared_env"))):  # fmt: skip
        if saved is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = saved


def shared_run(name: str, make) -> Path:
    """The folder of the session's run ``name``, made by ``make(folder)`` the first time any
    worker asks (the others wait for it, then read it). Tests read what is in it and write
    elsewhere. A ``make`` that fails leaves nothing: the next to ask runs it again (and
    fails the same way, in its own test).

    Parameters
    ----------
    name : str
        A folder name.
    make : callable
        ``make(folder)``: writes the run's files into ``folder`` (which exists, empty).

    Returns
    -------
    Path
    """
    root = Path(os.environ[_SHARED_ENV])
    folder = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (root / f"{name}.done").exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            try:
                make(folder)
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)
                raise
            (root / f"{name}.done").touch()
    return folder


def _make_liver_phantom_drag_run(d: Path) -> None:
    examples = Path(__file__).resolve().parents[1] / "examples"
    from needlekit.cli import main

    text = (examples / "liver_phantom_multi.yaml").read_text().replace(
        "  objective: min_length", "  objective: min_length\n  deformation: needle_drag"
    )
    scenario = d / "drag.yaml"
    scenario.write_text(text)
    plan = d / "multi.json"
    assert main(["multi", str(scenario), "--out", str(plan)]) == 0
    assert main(["execute", "--truth", "kinematic", str(scenario), str(plan), "--trials", "2", "--workers", "2",
                 "--out", str(d / "two")]) == 0  # fmt: skip
    assert main(["execute", "--truth", "kinematic", str(scenario), str(plan), "--trials", "2", "--replay-trial", "1",
                 "--out", str(d / "one"), "--report", str(d / "one" / "page.html")]) == 0  # fmt: skip


@pytest.fixture(scope="session")
def liver_phantom_drag_run() -> Path:
    """The liver phantom's three needles (examples/liver_phantom_multi.yaml) planned with
    the needle-drag deformation, inserted in two trials (two workers), and trial 1
    replayed alone: ``drag.yaml``, ``multi.json``, ``two/execute.json``,
    ``one/execute.json`` and ``one/page.html``, made once per session (tests/execute/
    test_execute_multi.py checks the run, tests/report/test_slicer_oracle.py its scene)."""
    return shared_run("liver-phantom-drag", _make_liver_phantom_drag_run)


#: One puncture trial (seed 3, the default 2 ms adaptation delay given on the command
#: line), kept with its command line: ``puncture_trial_seed3``.
PUNCTURE_TRIAL_ARGV = ["puncture", "--trials", "1", "--seed", "3", "--adaptation-delay-ms", "2",
                       "--no-report"]  # fmt: skip
#: The toy plan and two trials of it with the page the command draws: ``toy_execution``.
TOY_EXECUTION_ARGV = [
    ["plan", "{toy}", "--out", "{d}/plan.json"],
    ["execute", "--truth", "kinematic", "{toy}", "{d}/plan.json", "--trials", "2", "--seed", "0",
     "--out", "{d}/ex", "--report", "{d}/execute-command.html"],
]  # fmt: skip


def _make_puncture_trial(d: Path) -> None:
    from needlekit.cli import main

    assert main([*PUNCTURE_TRIAL_ARGV, "--out", str(d / "pu")]) in (0, 1)


def _make_toy_execution(d: Path) -> None:
    from needlekit.cli import main

    toy = str(Path(__file__).resolve().parents[1] / "examples" / "toy.yaml")
    for argv in TOY_EXECUTION_ARGV:
        assert main([a.replace("{d}", str(d)).replace("{toy}", toy) for a in argv]) == 0


@pytest.fixture(scope="session")
def puncture_trial_seed3() -> Path:
    """``puncture.json`` of :data:`PUNCTURE_TRIAL_ARGV`, made once per session
    (tests/test_report_cli.py draws it, tests/cli/test_adaptation_delay_flag.py reads the
    delay it records)."""
    return shared_run("puncture-trial-seed3", _make_puncture_trial) / "pu" / "puncture.json"


@pytest.fixture(scope="session")
def toy_execution() -> Path:
    """The folder of :data:`TOY_EXECUTION_ARGV`: ``plan.json``, ``ex/execute.json`` and
    ``execute-command.html``, made once per session, both commands exiting 0
    (tests/test_report_cli.py draws it, tests/report/test_slicer_oracle.py exports it)."""
    return shared_run("toy-execution", _make_toy_execution)


@pytest.fixture(scope="session")
def medrad_liver4_multi_plan(medrad_dir) -> Path:
    """``needlekit multi examples/medrad_liver4.yaml``'s plan (``multi.json``), made once
    per session (tests/planning/test_straight_coverage_cli.py checks its coverage,
    tests/execute/test_execute_medrad.py inserts it)."""

    def make(d: Path) -> None:
        from needlekit.cli import main

        saved = os.environ.get(MEDRAD_ENV)
        os.environ[MEDRAD_ENV] = str(medrad_dir)
        try:
            example = Path(__file__).resolve().parents[1] / "examples" / "medrad_liver4.yaml"
            assert main(["multi", str(example), "--out", str(d / "multi.json")]) == 0
        finally:
            if saved is None:
                os.environ.pop(MEDRAD_ENV, None)
            else:
                os.environ[MEDRAD_ENV] = saved

    return shared_run("medrad-liver4-multi", make) / "multi.json"


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


# -- pages in a real browser (headless Chromium; tests/test_browser.py and the study pages)

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
#: The one console message allowed, and why: with software GL, Chromium's GPU process
#: reports its own readback stalls (plotly.js reads pixels back to pick what is under the
#: mouse); a real GPU does not, and no line of the page caused it.
SOFTWARE_GL_NOTE = "GL Driver Message (OpenGL, Performance"
#: After the page's plots report a layout and every 3D view has drawn: the time given to
#: messages the last drawing may still log (the pages load nothing from the network).
SETTLE_S = 0.5
#: The window pages open in (px). SwiftShader draws each 3D view on the CPU, in proportion
#: to its pixels; what the page checks prove (each view drawn, the console clean) does not
#: depend on the size. A test that needs a given size sets it and puts this one back
#: (tests/test_browser.py's path-in-plain-sight check).
WINDOW = (700, 500)


def _chromium():
    if shutil.which(CHROMIUM) is None or shutil.which(CHROMEDRIVER) is None:
        pytest.skip(f"no {CHROMIUM} and {CHROMEDRIVER}: `make browser` installs Debian's packages")
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium: pip install -e .[test]")
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    o = Options()
    o.binary_location = CHROMIUM
    for a in (
        "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
        f"--window-size={WINDOW[0]},{WINDOW[1]}",
    ):  # fmt: skip
        o.add_argument(a)
    o.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=o)


@pytest.fixture(scope="session")
def browser():
    """Headless Chromium with software WebGL (SwiftShader), one per test process (each
    xdist worker starts its own); skips, saying why, where Chromium or its driver is
    missing (tests marked ``browser``)."""
    d = _chromium()
    yield d
    d.quit()


def _not_blank(png: bytes) -> bool:
    """More than 50 colours and a spread of the channels (0-1) above 0.02. The colours are
    counted as 24-bit integers: ``np.unique(..., axis=0)`` over RGB rows took about 0.3 s
    per view."""
    import io

    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.uint32)
    colours = np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2])
    return len(colours) > 50 and float((rgb / 255.0).std()) > 0.02


def _shot(browser, canvas) -> bytes:
    browser.execute_script("arguments[0].scrollIntoView()", canvas)
    return canvas.screenshot_as_png


@pytest.fixture
def rendered(browser):
    """``rendered(path, flat=False) -> (plots, pngs)``: open the page, wait up to 60 s for
    its plots to be laid out and up to 20 s for every 3D view to draw, then check that it
    has a 3D view (unless ``flat``), that each view is drawn (not blank) and that the
    console logged nothing but the software-GL note. ``pngs``: each view's screenshot."""
    import json
    import time

    def render(path, flat=False):
        browser.get(path.as_uri())
        count = "return document.querySelectorAll('.js-plotly-plot').length"
        ready = "return Array.from(document.querySelectorAll('.js-plotly-plot')).every(p => p._fullLayout)"
        for _ in range(600):
            if browser.execute_script(count) and browser.execute_script(ready):
                break
            time.sleep(0.1)
        browser.execute_script("window.scrollTo(0, document.body.scrollHeight)")
        deadline = time.monotonic() + 20.0
        # the page notes when plotly has drawn all its figures (``window.needlekitDrawn``,
        # report.html_page): screenshots are taken from then on, not of views half drawn
        drawn = "var d=window.needlekitDrawn;return !d||d.ms!==null"
        while not browser.execute_script(drawn) and time.monotonic() < deadline:
            time.sleep(0.1)
        while True:  # every 3D view's screenshot, until all are drawn (or 20 s)
            canvases = browser.find_elements("css selector", ".gl-container canvas")
            pngs = [_shot(browser, c) for c in canvases]
            if all(_not_blank(p) for p in pngs) or time.monotonic() >= deadline:
                break
            time.sleep(0.2)
        time.sleep(SETTLE_S)
        plots, logs = browser.execute_script(count), browser.get_log("browser")
        assert canvases or flat, f"{path.name}: no 3D view"
        for i, png in enumerate(pngs):
            assert _not_blank(png), f"{path.name}: 3D view {i} is blank"
        bad = [e for e in logs if SOFTWARE_GL_NOTE not in e["message"]]
        assert bad == [], json.dumps(bad, indent=1)
        return plots, pngs

    yield render
    # the browser outlives the test: leave no page drawing (an animated trial, say) while
    # the tests after it run
    browser.get("about:blank")
