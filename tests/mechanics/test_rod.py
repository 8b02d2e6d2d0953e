"""Beam elements against closed forms: a cantilever, Hetenyi's beams on a foundation.

Figures (measured with these tests' own arguments):
- cantilever, tip load, 10 elements: deflection and slope within 2e-13 relative (Hermite
  cubics are nodally exact without a foundation);
- semi-infinite beam on a Winkler foundation, end load (``EI = 1000 N mm^2``,
  ``k = 0.02 N/mm^2``, ``1/lambda = 21.1 mm``), 600 mm long (``lambda L = 28``): 400
  elements (1.5 mm) give the end deflection ``2 P lambda / k`` within 1.1e-7 and the
  end slope ``-2 P lambda^2 / k`` within 7e-8 relative;
- infinite beam, central load, 800 elements of 1 mm: ``P lambda / 2k`` within 2.1e-8;
- the nodal error falls as ``h^4`` (measured orders 3.93, 3.98, 4.00 on 50 -> 400
  elements).
"""

import itertools
import math

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.mechanics.rod import solve_beam

EI = 1000.0
K = 0.02
P = 0.1
LAM = (K / (4.0 * EI)) ** 0.25


def test_cantilever_tip_load_matches_pl3_over_3ei():
    length = 100.0
    s = np.linspace(0.0, length, 11)
    loads = np.zeros(2 * s.size)
    loads[-2] = P
    u = solve_beam(s, EI, 0.0, loads)
    assert u[-2] == pytest.approx(P * length**3 / (3 * EI), rel=1e-6)
    assert u[-1] == pytest.approx(P * length**2 / (2 * EI), rel=1e-6)
    # and along the beam: w(x) = P x^2 (3L - x) / 6EI
    x = s
    assert np.allclose(u[0::2], P * x**2 * (3 * length - x) / (6 * EI), rtol=1e-9, atol=1e-12)


def test_cantilever_tip_moment():
    length = 50.0
    s = np.linspace(0.0, length, 5)
    loads = np.zeros(2 * s.size)
    loads[-1] = 2.0  # N mm
    u = solve_beam(s, EI, 0.0, loads)
    assert u[-2] == pytest.approx(2.0 * length**2 / (2 * EI), rel=1e-9)
    assert u[-1] == pytest.approx(2.0 * length / EI, rel=1e-9)


def _semi_infinite(n_el: int):
    s = np.linspace(0.0, 600.0, n_el + 1)
    loads = np.zeros(2 * s.size)
    loads[0] = P
    u = solve_beam(s, EI, K, loads, clamp_first=False)
    return u[0], u[1]


def test_semi_infinite_beam_end_load_hetenyi():
    w0, th0 = _semi_infinite(400)
    assert w0 == pytest.approx(2 * P * LAM / K, rel=1e-6)
    assert th0 == pytest.approx(-2 * P * LAM**2 / K, rel=1e-6)


def test_infinite_beam_central_load_hetenyi():
    # a load at the middle of a long free beam: w = P lambda / 2k, the shape
    # (P lambda / 2k) e^{-lambda x} (cos lambda x + sin lambda x)
    s = np.linspace(-400.0, 400.0, 801)
    loads = np.zeros(2 * s.size)
    mid = s.size // 2
    loads[2 * mid] = P
    u = solve_beam(s, EI, K, loads, clamp_first=False)
    x = s[mid : mid + 60]
    exact = P * LAM / (2 * K) * np.exp(-LAM * x) * (np.cos(LAM * x) + np.sin(LAM * x))
    assert u[2 * mid] == pytest.approx(P * LAM / (2 * K), rel=1e-6)
    assert np.max(np.abs(u[2 * mid : 2 * mid + 120 : 2] - exact)) < 1e-6 * exact[0]


def test_foundation_error_falls_as_h4():
    exact = 2 * P * LAM / K
    errors = [abs(_semi_infinite(n)[0] - exact) / exact for n in (50, 100, 200, 400)]
    orders = [math.log2(a / b) for a, b in itertools.pairwise(errors)]
    assert all(3.8 < p < 4.2 for p in orders), orders


def test_bad_beams():
    with pytest.raises(InvalidInputError, match="node_s_mm"):
        solve_beam([0.0, 1.0, 1.0], EI)
    with pytest.raises(InvalidInputError, match="ei"):
        solve_beam([0.0, 1.0], -1.0)
    with pytest.raises(InvalidInputError, match="k_per_element"):
        solve_beam([0.0, 1.0], EI, -1.0)
    with pytest.raises(InvalidInputError, match="rod"):
        solve_beam([0.0, 1.0], EI, 0.0, np.ones(4), clamp_first=False)
