"""The mechanical needle under a closed loop's commands: a new spin and duty every step.

The bound on the tip's move per step comes from the model's own closed form. The tip sits
off its channel by the shaft's compliance times the bevel's load; for a semi-infinite
beam on the foundation (``lambda = (k / 4 EI)^(1/4)``) with the unsupported bevel of
length ``a`` overhanging its end, the tip's compliance is

    C = 2 lambda / k + 4 lambda^2 a / k + 4 lambda^3 a^2 / k + a^3 / 3 EI,

which the rod's compliance approaches from below as the depth grows (a guide clamped
nearer makes it stiffer). The load on the bevel face is the mean of the commands over the
last bevel length ``L_b`` of depth, so one step of ``ds`` changes it by at most
``2 Q min(1, ds / L_b)`` (a flip of the full load). Hence, per step,

    |tip move| <= 1.05 ds + 2 Q C min(1, ds / L_b).

Measured (nitinol, seed 3, spins N(0, 0.3 rad), duties U(0, 1), 150 mm): with the wedge's
tip load the worst move is the step itself, 0.92-0.94 of the bound in lung at 0.05, 0.25
and 4 mm steps and 0.89 in chicken at 0.25 mm. With the earlier load (the whole axial
resistance through the face) a duty change moved the tip by ``C dQ`` at once: 9.7 mm per
0.05 mm step in lung past 60 mm.
"""

import math

import numpy as np
import pytest

from needlekit.mechanics.insertion import MechanicalNeedle


def _compliance(sim):
    lam = (sim.k / (4.0 * sim.ei)) ** 0.25
    a, k = sim.unsupported_mm, sim.k
    return 2 * lam / k + 4 * lam**2 * a / k + 4 * lam**3 * a * a / k + a**3 / (3 * sim.ei)


def _bound(sim, ds):
    q = sim.tip_load.lateral_n
    return 1.05 * ds + 2.0 * q * _compliance(sim) * min(1.0, ds / sim.needle.bevel_length_mm)


def _random_run(tissue, ds, depth, seed=3, **kw):
    sim = MechanicalNeedle(np.eye(4), "nitinol", tissue, **kw)
    kmax = MechanicalNeedle(np.eye(4), "nitinol", tissue).kappa_max_per_mm
    rng = np.random.default_rng(seed)
    pts = [sim.pose[:3, 3].copy()]
    for _ in range(round(depth / ds)):
        sim.step(rng.normal(0.0, 0.3), 0.0, 0.0, 0.0)  # the loop's spin, in between
        sim.step(0.0, rng.uniform(0.0, 1.0) * kmax, ds, 0.025)
        pts.append(sim.pose[:3, 3].copy())
    return sim, np.array(pts)


@pytest.mark.parametrize(
    ("tissue", "ds", "depth"),
    [pytest.param("lung", 0.05, 150.0, marks=pytest.mark.slow), ("lung", 0.25, 150.0), ("lung", 4.0, 148.0), ("chicken", 0.25, 150.0),
     ("liver", 0.01, 4.0)],
)  # fmt: skip
def test_random_commands_move_the_tip_within_the_closed_form_bound(tissue, ds, depth):
    sim, pts = _random_run(tissue, ds, depth)
    assert sim.inserted_mm == pytest.approx(depth)
    moves = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert np.all(np.isfinite(pts))
    assert moves.max() <= _bound(sim, ds)
    # the tip advances: never less than the step's depth minus the bend's chord deficit
    assert pts[-1, 2] > 0.5 * depth


@pytest.mark.parametrize(
    ("tissue", "tol"), [("chicken", 1e-4), pytest.param("lung", 1e-4, marks=pytest.mark.slow)]
)
def test_random_commands_path_matches_a_refined_run(tissue, tol):
    """Half the elements and a quarter of the sub-step, the same commands: same path
    (measured 1.4e-5 mm in chicken, 1.6e-6 mm in lung over 150 mm)."""
    _, a = _random_run(tissue, 0.5, 150.0)
    _, b = _random_run(tissue, 0.5, 150.0, element_mm=0.5, max_substep_mm=0.25)
    assert np.abs(a - b).max() < tol


def test_a_flip_deep_in_the_tissue_moves_the_tip_the_same_at_any_depth():
    """The bevel held, then turned over for one 0.05 mm step: the tip's move is the
    load's change (2 Q ds / L_b) times the shaft's compliance, which stops growing once
    the shaft is a few foundation lengths (1/lambda = 52 mm in lung) deep."""
    moves = []
    for depth in (100.0, 125.0, 150.0):
        sim = MechanicalNeedle(np.eye(4), "nitinol", "lung")
        kmax = sim.kappa_max_per_mm
        for _ in range(round(depth)):
            sim.step(0.0, kmax, 1.0, 0.025)
        before = sim.pose[:3, 3].copy()
        sim.step(math.pi, 0.0, 0.0, 0.0)
        assert np.allclose(sim.pose[:3, 3], before)  # a spin in place moves nothing
        sim.step(0.0, kmax, 0.05, 0.025)
        move = float(np.linalg.norm(sim.pose[:3, 3] - before))
        assert move <= _bound(sim, 0.05)
        moves.append(move)
    assert max(moves) < 1.05 * min(moves), moves


def test_how_the_loop_slices_the_commands_does_not_change_the_path():
    """A step of 0.5 mm, or two of 0.25 mm with the same spin and duty: the bevel's load
    is a function of the depth cut, not of the steps."""
    rng = np.random.default_rng(5)
    cmds = [(rng.normal(0.0, 0.3), rng.uniform(0.0, 1.0)) for _ in range(120)]
    a = MechanicalNeedle(np.eye(4), "nitinol", "chicken")
    b = MechanicalNeedle(np.eye(4), "nitinol", "chicken", max_substep_mm=0.25)
    kmax = a.kappa_max_per_mm
    c = MechanicalNeedle(np.eye(4), "nitinol", "chicken", max_substep_mm=0.25)
    for spin, duty in cmds:
        a.step(spin, duty * kmax, 0.5, 0.0)
        b.step(spin, duty * kmax, 0.25, 0.0)
        b.step(0.0, duty * kmax, 0.25, 0.0)
        c.step(spin, duty * kmax, 0.5, 0.0)
    assert np.allclose(b.pose, c.pose, atol=1e-9)  # same sub-steps, sliced differently
    assert np.linalg.norm(a.pose[:3, 3] - b.pose[:3, 3]) < 1e-3  # measured 7.5e-5 mm
