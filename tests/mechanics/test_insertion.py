"""The mechanical needle's insertion: oracles, limits, trends and the truth protocol.

The configurations are small and stiff (a 0.5 mm nitinol wire in a 100 kPa tissue,
``1/lambda = 10.8 mm``) so each long insertion takes a fraction of a second.

Measured (these tests' arguments): with the tissue holding the shaft up to the tip
(``unsupported_mm = 0``) the steady curvature of a held bevel approaches the closed form
``kappa = Q / (2 lambda EI)`` of a semi-infinite beam on a Winkler foundation with end
force ``Q``, zero end moment and zero end slope off the channel: relative error 1.9e-3
at a 2 mm sub-step, 2.3e-4 at 1 mm, 1.5e-5 at 0.5 mm; successive differences fall at
orders 2.9 and 2.5 (Heun's predictor-corrector advance: 2 in theory), on a path of radius
95 mm (1.6 rad over 150 mm).
"""

import math

import numpy as np
import pytest

from needlekit.mechanics.insertion import MechanicalNeedle, steady_curvature
from needlekit.mechanics.materials import NeedleSpec, TissueSpec
from needlekit.mechanics.shaft import solve_shaft
from needlekit.mechanics.tip_load import bevel_tip_load

WIRE = NeedleSpec(0.5, 0.0, 75e3, math.radians(30), "wire")
# a rubber-stiff tissue bends the wire at a radius of 82.5 mm (1/lambda = 3.29 mm), a
# path far from straight; elements and sub-steps of FINE keep 1/lambda about 11 of them
STIFF = TissueSpec(8.0, 0.5, 0.45, 0.0, 0.0, "stiff")  # held up to the tip
STIFF_BEVEL = TissueSpec(8.0, 0.5, 0.45, 0.0, None, "stiff-bevel")  # bevel unsupported
H = 0.3
FINE = {"element_mm": H, "max_substep_mm": H}


def _closed_form(needle, tissue):
    ei = needle.bending_stiffness_nmm2
    lam = (tissue.foundation_modulus(needle) / (4 * ei)) ** 0.25
    return bevel_tip_load(needle, tissue).lateral_n / (2 * lam * ei), lam


def _heading(sim):
    t = sim.pose[:3, 2]
    return math.atan2(-t[1], t[2])


def _insert(sim, length, kappa, ds=1.0, spin=0.0):
    sim.step(spin, kappa, 0.0, 0.0)
    pts = []
    for _ in range(round(length / ds)):
        sim.step(0.0, kappa, ds, 0.025)
        pts.append(sim.pose[:3, 3].copy())
    return np.array(pts)


def _fit_circle(y, z):
    a = np.column_stack([y, z, np.ones_like(y)])
    c = np.linalg.lstsq(a, y * y + z * z, rcond=None)[0]
    yc, zc = c[0] / 2, c[1] / 2
    r = math.sqrt(c[2] + yc * yc + zc * zc)
    return r, float(np.sqrt(np.mean((np.hypot(y - yc, z - zc) - r) ** 2)))


def test_steady_curvature_meets_the_closed_form_at_order_two():
    exact, _ = _closed_form(WIRE, STIFF)
    assert 1 / exact == pytest.approx(82.50, abs=0.01)  # a strongly bending path
    k = [steady_curvature(WIRE, STIFF, 10.0, H, sub * H) for sub in (2.0, 1.0, 0.5)]
    assert abs(k[1] / exact - 1) < 5e-4
    assert abs(k[2] / exact - 1) < 1e-4
    order = math.log2(abs(k[0] - k[1]) / abs(k[1] - k[2]))
    assert 1.7 < order < 3.3, order


def test_large_bend_is_an_arc_after_the_transient():
    sim = MechanicalNeedle(np.eye(4), WIRE, STIFF, **FINE)
    kmax = sim.kappa_max_per_mm
    pts = _insert(sim, 150.0, kmax)
    assert _heading(sim) > 1.5  # 86 degrees and more: far from the straight line
    cut = sim.channel_points_mm()
    late = sim.channel.depth_mm > 60.0
    r_cut, rms_cut = _fit_circle(cut[late, 1], cut[late, 2])
    assert r_cut == pytest.approx(1 / kmax, rel=1e-3)
    assert rms_cut < 2e-3
    # the tip rides inside the channel's arc by its elastic offset
    r_tip, rms_tip = _fit_circle(pts[60:, 1], pts[60:, 2])
    offset = np.linalg.norm(sim.solution.offsets_mm[-1])
    assert r_tip == pytest.approx(r_cut - offset, abs=0.02)
    assert rms_tip < 2e-3
    # offsets off the channel stay small beside the bend: the linearisation's premise
    assert np.max(np.abs(sim.solution.offsets_mm)) < 0.01 * r_cut


def test_kinematic_limit_flexible_needle_in_stiff_tissue():
    """Holding kappa = 1/100 mm, a needle ever more flexible against the tissue follows
    ever closer the unicycle's arc: the residual to the best-fit circle of the whole tip
    path shrinks toward zero."""
    tissue = TissueSpec(0.1, 0.0, unsupported_mm=0.0)
    residuals = []
    for e in (7.5e3, 750.0, 75.0):
        probe = NeedleSpec(0.5, 0.0, e, 0.5)
        k = tissue.foundation_modulus(probe)
        ei = probe.bending_stiffness_nmm2
        lam = (k / (4 * ei)) ** 0.25
        bevel = math.atan(0.5 * k * 0.25 / (2 * lam * ei * 0.01))  # Q = 2 lambda EI kappa
        needle = NeedleSpec(0.5, 0.0, e, bevel)
        h = min(1.0, 0.25 / lam)
        sim = MechanicalNeedle(np.eye(4), needle, tissue, element_mm=h, max_substep_mm=h)
        pts = np.vstack([np.zeros(3), _insert(sim, 100.0, 1.0)])
        r, rms = _fit_circle(pts[:, 1], pts[:, 2])
        assert r == pytest.approx(100.0, rel=5e-3)
        residuals.append(rms)
    assert residuals[0] > residuals[1] > residuals[2]
    assert residuals[2] < 3e-3


def test_curvature_trends_bevel_tissue_needle():
    chicken = TissueSpec.preset("chicken")
    nitinol = NeedleSpec.preset("nitinol")

    def kappa(n, t):
        return steady_curvature(n, t, 10.0, 2.0, 2.0)

    by_bevel = [kappa(nitinol.with_bevel_deg(a), chicken) for a in (15.0, 30.0, 60.0)]
    assert by_bevel[0] > by_bevel[1] > by_bevel[2] > 0  # sharper bevel, tighter path
    by_tissue = [kappa(nitinol, chicken.scaled(f)) for f in (0.5, 1.0, 2.0)]
    assert by_tissue[0] < by_tissue[1] < by_tissue[2]  # stiffer tissue, tighter path
    stiffer_needle = NeedleSpec(0.83, 0.0, 200e3, nitinol.bevel_angle_rad)
    assert kappa(stiffer_needle, chicken) < by_bevel[1]  # stiffer needle, wider path


def test_duty_zero_is_straight_and_duty_scales_the_curvature():
    sim = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    pts = _insert(sim, 40.0, 0.0, ds=2.0)
    assert np.max(np.abs(pts[:, :2])) < 1e-12
    assert pts[-1, 2] == pytest.approx(40.0, abs=1e-9)
    kmax = sim.kappa_max_per_mm
    turns = []
    for f in (1.0, 0.5):
        s = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
        _insert(s, 60.0, f * kmax)
        h0 = _heading(s)
        _insert(s, 20.0, f * kmax)
        turns.append((_heading(s) - h0) / 20.0)
    assert turns[0] == pytest.approx(kmax, rel=1e-3)
    assert turns[1] == pytest.approx(0.5 * kmax, rel=2e-3)
    # over-commanded: clipped at the held bevel
    s = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    _insert(s, 30.0, 10 * kmax)
    s2 = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    _insert(s2, 30.0, kmax)
    assert np.allclose(s.pose, s2.pose, atol=1e-12)


def test_base_spin_by_pi_flips_the_bend():
    a = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    b = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    pa = _insert(a, 40.0, a.kappa_max_per_mm)
    pb = _insert(b, 40.0, b.kappa_max_per_mm, spin=math.pi)
    assert pa[-1, 1] < -1.0  # toward the tip's -y axis, as the planner's arcs
    assert np.allclose(pb[:, 1], -pa[:, 1], atol=1e-9)
    assert np.allclose(pb[:, 2], pa[:, 2], atol=1e-9)
    # a negative command is the same as spinning by pi
    c = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    pc = _insert(c, 40.0, -c.kappa_max_per_mm)
    assert np.allclose(pc, pb, atol=1e-9)


def test_shaft_lags_behind_the_tip():
    """The shaft takes, at each depth, the direction the tip had there: it lags behind the
    tip along the channel. Its offset off the channel lives within a few 1/lambda of the
    tip (and of the entry, where the straight guide meets the bent channel)."""
    sim = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    kmax = sim.kappa_max_per_mm
    _insert(sim, 100.0, kmax)
    _, lam = _closed_form(WIRE, STIFF_BEVEL)
    sol = sim.solution
    behind = sol.s_mm[-1] - sol.s_mm
    inner = (behind > 4.0 / lam) & (sol.s_mm > 10.0 + 4.0 / lam)
    off = np.linalg.norm(sol.offsets_mm, axis=1)
    assert off[-1] > 0.05  # about kappa / lambda^2
    assert off[inner].max() < 0.05 * off[-1]  # e^{-4} decay
    shaft_t = sol.tangents + sol.slopes[:, :1] * sol.e_x + sol.slopes[:, 1:] * sol.e_y
    shaft_t /= np.linalg.norm(shaft_t, axis=1, keepdims=True)
    _, cut_t, _ = sim.channel.sample(sol.s_mm[inner] - 10.0)
    assert np.max(np.linalg.norm(shaft_t[inner] - cut_t, axis=1)) < 5e-3  # vs lag >= 0.4 rad
    lag = np.arccos(np.clip(shaft_t[inner] @ sim.pose[:3, 2], -1, 1))
    assert np.allclose(lag, kmax * behind[inner], rtol=0.02)
    # turned over, the tip turns back at once; the shaft stays in the S it cut
    h0 = _heading(sim)
    _insert(sim, 20.0, kmax, spin=math.pi)
    h1 = _heading(sim)
    _insert(sim, 10.0, kmax)
    assert h1 < h0 and _heading(sim) < h1
    cut = sim.channel_points_mm()
    shaft = sim.shaft_points_mm()[sim.solution.s_mm > 10.0]
    dist = np.min(np.linalg.norm(shaft[:, None, :] - cut[None, :, :], axis=2), axis=1)
    assert dist.max() < 1.0
    assert np.max(np.abs(shaft[:, 1])) > 10.0


def test_truth_protocol_pose_frames_and_zero_insertion():
    start = np.eye(4)
    start[:3, 3] = (10.0, -5.0, 3.0)
    sim = MechanicalNeedle(start, WIRE, STIFF_BEVEL, **FINE)
    assert np.array_equal(sim.pose, start) and sim.inserted_mm == 0.0
    out = sim.step(0.3, 0.0, 0.0, 0.1)  # spin only: the frame turns about z
    c, s = math.cos(0.3), math.sin(0.3)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    assert np.allclose(out[:3, :3], rz, atol=1e-12)
    assert np.allclose(out[:3, 3], start[:3, 3]) and sim.inserted_mm == 0.0
    out[0, 0] = 99.0  # step returns a copy
    assert sim.pose[0, 0] != 99.0
    sim.step(-0.3, sim.kappa_max_per_mm, 25.0, 1.0)
    assert sim.inserted_mm == pytest.approx(25.0)
    rot = sim.pose[:3, :3]
    assert np.allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    phi = _heading(sim)
    rx = np.array(
        [[1, 0, 0], [0, math.cos(phi), -math.sin(phi)], [0, math.sin(phi), math.cos(phi)]]
    )
    assert np.allclose(rot, rx, atol=1e-12)  # a planar bend about x, as the arcs' Rx


def test_shaft_loads_and_moving_anchors():
    sim = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    assert sim.shaft_loads()[0].shape == (0, 3)
    _insert(sim, 80.0, 0.0, ds=4.0)
    pts, forces = sim.shaft_loads()
    assert pts.shape == forces.shape and pts.shape[1] == 3
    assert np.allclose(forces[:-1], 0.0)  # straight, no bevel load: no lateral force
    assert forces[-1] == pytest.approx([0.0, 0.0, -bevel_tip_load(WIRE, STIFF_BEVEL).axial_n])
    tip0 = sim.pose[:3, 3].copy()
    sim.displace_channel(lambda p: np.tile([0.0, 0.5, 0.0], (p.shape[0], 1)))
    assert sim.pose[:3, 3] - tip0 == pytest.approx([0.0, 0.5, 0.0], abs=1e-3)
    pts, forces = sim.shaft_loads()
    s = sim.solution.s_mm
    assert np.allclose(forces[s < 10.0 - 1e-9], 0.0)  # the free gap
    # near the tissue's entry the shaft is pulled toward the moved anchors (+y)
    assert forces[(s > 10.0) & (s < 14.0), 1].max() > 0
    with pytest.raises(ValueError, match="displacement_mm"):
        sim.displace_channel(lambda p: np.zeros((2, 3)))


def test_the_foundation_takes_the_tissues_millimetre_by_millimetre_modulus():
    """The inhomogeneity scales the foundation per millimetre of depth: factors of 2
    everywhere are the tissue twice as stiff, to the last digit; factors of 1 are none;
    a soft millimetre lets the shaft off its channel there and only there."""
    sim = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, **FINE)
    _insert(sim, 30.0, sim.kappa_max_per_mm, ds=2.0)
    args = (sim.channel, sim.guide, sim.gap_mm, sim.inserted_mm, sim.ei)
    rest = (sim.unsupported_mm, (0.02, -0.05), H)
    base = solve_shaft(*args, sim.k, *rest)
    double = solve_shaft(*args, 2.0 * sim.k, *rest)
    assert np.array_equal(solve_shaft(*args, sim.k, *rest, k_by_mm=np.full(40, 2.0)).offsets_mm,
                          double.offsets_mm)  # fmt: skip
    assert np.array_equal(solve_shaft(*args, sim.k, *rest, k_by_mm=np.ones(40)).offsets_mm,
                          base.offsets_mm)  # fmt: skip
    soft = np.ones(40)
    soft[10] = 0.0  # the tissue between 10 and 11 mm deep holds nothing
    held = solve_shaft(*args, sim.k, *rest, k_by_mm=soft)
    depth = held.s_mm - sim.gap_mm
    moved = np.linalg.norm(held.offsets_mm - base.offsets_mm, axis=1)
    assert moved[(depth > 10.0) & (depth < 11.0)].max() > 10 * moved[depth < 2.0].max()


def test_inhomogeneity_is_seeded_and_off_by_default():
    def run(seed):
        sim = MechanicalNeedle(
            np.eye(4), WIRE, STIFF_BEVEL, np.random.default_rng(seed), inhomogeneity=0.2, **FINE
        )
        return _insert(sim, 30.0, 0.5 * sim.kappa_max_per_mm, ds=2.0)

    a, b, c = run(1), run(1), run(2)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    assert np.abs(a[:, 0]).max() > 1e-6  # the lateral push leaves the bending plane


def test_prebent_tip_bends_tighter_than_the_bevel_alone():
    """A pre-bent tip (Majewicz et al.'s tip-steerable needles) turns the path at radii of
    5-15 cm where the bevel alone gives metres; more bend, tighter path. Indicative: the
    shaft's slope off the channel reaches 0.1-0.4 rad, past the small-offset premise."""
    nitinol = NeedleSpec.preset("nitinol")
    chicken = TissueSpec.preset("chicken")
    radii = [
        1 / steady_curvature(nitinol.with_prebend(b, 5.0), chicken, 10.0, 2.0, 2.0)
        for b in (10.0, 20.0)
    ]
    assert 1 / steady_curvature(nitinol, chicken, 10.0, 2.0, 2.0) > 1000.0
    assert 100.0 < radii[0] < 200.0
    assert 50.0 < radii[1] < 100.0
    # duty cycling averages the pre-bend too: duty 0 is straight
    sim = MechanicalNeedle(np.eye(4), nitinol.with_prebend(20.0, 5.0), chicken)
    pts = _insert(sim, 20.0, 0.0, ds=5.0)
    assert np.max(np.abs(pts[:, :2])) < 1e-12


def test_a_prebent_tip_leaves_its_introducer_along_its_aim():
    """Straight in its introducer until it cuts, a 20 degree pre-bent tip turns as its
    bend leaves it: by the rest curvature times the depth (0.4 degrees after 0.1 mm, 4
    after 1 mm), the full 20 degrees once its 5 mm are in the tissue. Counted as bent
    before the entry, it turned 20.8 degrees and moved 0.86 mm sideways in its first
    0.1 mm."""
    needle = NeedleSpec.preset("nitinol").with_prebend(20.0, 5.0)
    sim = MechanicalNeedle(np.eye(4), needle, TissueSpec.preset("lung"))
    kmax = sim.kappa_max_per_mm
    turns = {}
    for depth in (0.1, 1.0, 5.0):
        while sim.inserted_mm < depth - 1e-9:
            sim.step(0.0, kmax, 0.1, 0.025)
        turns[depth] = math.degrees(math.acos(np.clip(sim.pose[2, 2], -1.0, 1.0)))
        if depth == 0.1:
            assert np.linalg.norm(sim.pose[:2, 3]) < 0.03
    assert turns[0.1] == pytest.approx(0.4, abs=0.05)
    assert turns[1.0] == pytest.approx(4.0, abs=0.1)
    assert turns[5.0] == pytest.approx(20.0, abs=0.2)


def test_the_path_does_not_depend_on_the_step_size():
    """40 mm inserted in 400 steps of 0.1 mm or 10 of 4 mm, sub-steps of at most 0.1 mm
    (a tenth of that while the tissue takes hold): the same tip, to 1e-4 mm. How finely
    the sub-steps cut the path is the discretisation, held by the order-two test."""
    tips = []
    for ds in (0.1, 4.0):
        sim = MechanicalNeedle(np.eye(4), WIRE, STIFF_BEVEL, element_mm=H, max_substep_mm=0.1)
        kmax = sim.kappa_max_per_mm
        for _ in range(round(40.0 / ds)):
            sim.step(0.0, kmax, ds, 0.025)
        tips.append(sim.pose[:3, 3])
        assert sim.inserted_mm == pytest.approx(40.0, abs=1e-9)
    assert np.linalg.norm(tips[0] - tips[1]) < 1e-4
    assert abs(tips[0][1]) > 10.0


def test_a_tip_that_cannot_bend_goes_straight_whatever_the_command():
    stuck = TissueSpec(0.1, 0.5, 0.45, 5.0, 0.0, "stuck")  # friction cancels Q
    sim = MechanicalNeedle(np.eye(4), WIRE, stuck)
    assert sim.kappa_max_per_mm == 0.0
    pts = _insert(sim, 10.0, 0.01, ds=2.0)
    assert np.max(np.abs(pts[:, :2])) < 1e-12
