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

import pytest

from needlekit.errors import InvalidInputError
from needlekit.io.medrad import MEDRAD_ENV, load_medrad, medrad_root

_CACHE_ENV = "NEEDLEKIT_CACHE_DIR"
_saved: dict = {}


def pytest_configure(config):
    # Tests never read or write the user's prepared-anatomy cache: the whole session (and
    # the commands it starts) uses a temporary one, removed at the end.
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
