"""The placed-needle VFIs: the held needle's shaft against the needles
already in place. The distance against brute force and closed forms, its Jacobian against
finite differences, and the closed loop: a motion that would sweep the shaft through a
placed needle stops at the safe gap, and crosses it without the rows."""

import numpy as np
import pytest

from needlekit.control import _tick
from needlekit.control.controller import ControllerSettings, GuideLine, Step, control_step
from needlekit.control.panda import PandaModel
from needlekit.control.qp import QPStatus
from needlekit.control.trial import TrialSetup
from needlekit.errors import InvalidInputError

Q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
NO_J = np.zeros((3, 0))
NEEDLE = np.eye(4)
NEEDLE[2, 3] = 100.0  # Tang et al.'s nominal needle: the tip 100 mm beyond the flange


def _arm():
    return PandaModel(flange_T_tip=NEEDLE)


def _sq_distance(tip, axis, length, segs):
    return _tick.shaft_rows(
        tip, axis, NO_J, NO_J, length, np.asarray(segs, float), 0.0, 0.0, np.zeros((0, 0)),
        np.zeros(0), 0, False,
    )  # fmt: skip


def test_closed_forms():
    tip, axis = np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])  # shaft z in [-100, 0]
    # parallel, 5 mm aside and overlapping: 25 mm^2
    assert _sq_distance(tip, axis, 100.0, [[[5.0, 0, -20], [5.0, 0, -80]]]) == pytest.approx(25.0)
    # crossing at right angles 3 mm off the shaft: 9 mm^2
    assert _sq_distance(tip, axis, 100.0, [[[-50, 3.0, -40], [50, 3.0, -40]]]) == pytest.approx(9.0)
    # beyond the tip, along the axis: the tip is the closest point (4 mm)
    assert _sq_distance(tip, axis, 100.0, [[[0, 0, 4.0], [0, 0, 30.0]]]) == pytest.approx(16.0)
    # beyond the flange end (100 mm back), 10 mm further on: 100 mm^2
    assert _sq_distance(tip, axis, 100.0, [[[0, 0, -110.0], [0, 0, -150.0]]]) == pytest.approx(
        100.0
    )
    # a needle of no length is its tip
    assert _sq_distance(tip, axis, 0.0, [[[3.0, 4.0, -10], [3.0, 4.0, 10]]]) == pytest.approx(25.0)
    # the smallest of several
    segs = [[[5.0, 0, -20], [5.0, 0, -80]], [[-50, 3.0, -40], [50, 3.0, -40]]]
    assert _sq_distance(tip, axis, 100.0, segs) == pytest.approx(9.0)


def test_against_brute_force():
    rng = np.random.default_rng(3)
    s = np.linspace(0.0, 1.0, 2001)
    for _ in range(30):
        tip = rng.uniform(-20, 20, 3)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        seg = rng.uniform(-40, 40, (1, 2, 3))
        got = _sq_distance(tip, axis, 60.0, seg)
        shaft = tip - np.outer(s * 60.0, axis)
        other = seg[0, 0] + np.outer(s, seg[0, 1] - seg[0, 0])
        # the closest pair on 2001 x 2001 samples (by chunks)
        brute = min(
            float((((shaft[i : i + 200, None] - other[None]) ** 2).sum(-1)).min())
            for i in range(0, len(s), 200)
        )
        assert got <= brute + 1e-9
        assert got >= brute - 0.2 * np.sqrt(brute) - 0.02  # the sampling step is 0.03 mm


def test_row_is_the_rate_of_the_squared_distance():
    m = _arm()
    st = m.state(Q0)
    length = float(np.linalg.norm(m.flange_T_tip[:3, 3]))
    # a placed needle crossing 6 mm off the shaft's middle
    mid = st.tip_mm - 0.5 * length * st.needle_axis
    side = np.cross(st.needle_axis, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    other = np.cross(st.needle_axis, side)
    c = mid + 6.0 * side
    segs = np.array([[c - 40 * other, c + 40 * other]])
    A, bu = np.zeros((1, 7)), np.zeros(8)
    d0 = _tick.shaft_rows(
        st.tip_mm, st.needle_axis, st.tip_jacobian, st.axis_jacobian, length, segs, 4.0, 2.0,
        A, bu, 0, True,
    )  # fmt: skip
    assert d0 == pytest.approx(36.0, abs=1e-6)
    assert bu[7] == pytest.approx(2.0 * (36.0 - 4.0), abs=1e-6)
    rng = np.random.default_rng(0)
    for _ in range(5):
        qd = rng.normal(size=7)
        h = 1e-6
        s2 = m.state(Q0 + h * qd)
        d1 = _sq_distance(s2.tip_mm, s2.needle_axis, length, segs)
        assert -A[0] @ qd == pytest.approx((d1 - d0) / h, rel=1e-3, abs=1e-4)


def _sweep(placed, steps=6000):
    """APPROACH 80 mm sideways with the axis held; the smallest real gap on the way (the
    patient cylinder shrunk to 1 mm: its rows are not what is tested here)."""
    m = _arm()
    cfg = ControllerSettings(patient_radius_mm=1.0)
    st = m.state(Q0)
    g = GuideLine(st.tip_mm - 300.0 * st.needle_axis, -st.needle_axis)  # u = today's axis
    goal = st.tip_mm + np.array([0.0, 80.0, 0.0])
    length = float(np.linalg.norm(m.flange_T_tip[:3, 3]))
    q, gaps, statuses = Q0.copy(), [], set()
    for _ in range(steps):
        out = control_step(m, q, Step.APPROACH, g, cfg, desired_mm=goal, placed=placed)
        statuses.add(out.status)
        q = q + 1e-3 * out.q_dot
        s = m.state(q)
        gaps.append(np.sqrt(_sq_distance(s.tip_mm, s.needle_axis, length, SEG)) - 2.0)
    return min(gaps), np.linalg.norm(m.state(q).tip_mm - goal), statuses


def _crossbar():
    m = _arm()
    st = m.state(Q0)
    length = float(np.linalg.norm(m.flange_T_tip[:3, 3]))
    c = st.tip_mm + np.array([0.0, 40.0, 0.0]) - 0.5 * length * st.needle_axis
    n = np.cross(st.needle_axis, [0.0, 1.0, 0.0])
    n /= np.linalg.norm(n)
    return np.array([[c - 60.0 * n, c + 60.0 * n]])


SEG = _crossbar()


def test_the_shaft_stops_at_the_safe_gap_and_crosses_without_the_rows():
    gap_free, reached_free, _ = _sweep(None)
    assert reached_free < 10.0  # 80 mm at gain 0.5 /s for 6 s: nothing in the way
    assert gap_free < 0.0  # without the rows the shaft goes through the placed needle
    gap, reached, statuses = _sweep(SEG)
    assert statuses == {QPStatus.OPTIMAL}
    assert gap >= ControllerSettings().needle_gap_mm - 0.02  # kept (discrete steps)
    assert reached > 20.0  # and the goal behind it is not reached


def test_setup_refuses_bad_segments():
    m = _arm()
    a = np.zeros(12)
    with pytest.raises(InvalidInputError, match="placed_needles"):
        TrialSetup(m, a, a, Q0, np.zeros(3), np.array([0, 0, 1.0]), placed_needles=np.zeros((1, 3)))
    with pytest.raises(InvalidInputError, match="placed_needles_true"):
        TrialSetup(
            m, a, a, Q0, np.zeros(3), np.array([0, 0, 1.0]),
            placed_needles_true=np.zeros((1, 2, 3)),
        )  # fmt: skip


def test_control_step_refuses_placed_needles_that_are_not_segments():
    m = _arm()
    st = m.state(Q0)
    g = GuideLine(st.tip_mm - 300.0 * st.needle_axis, -st.needle_axis)
    with pytest.raises(InvalidInputError, match="placed"):
        control_step(m, Q0, Step.ALIGN, g, placed=[[0.0, 0.0, 0.0]])
