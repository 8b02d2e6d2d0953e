"""The compiled kernels agree with their numpy references."""

import numpy as np

from needlekit.mechanics.insertion import MechanicalNeedle
from needlekit.mechanics.materials import NeedleSpec, TissueSpec
from needlekit.mechanics.shaft import solve_shaft


def _bent_needle():
    needle = NeedleSpec(0.5, 0.0, 75e3, 0.5).with_prebend(15.0, 3.0)
    sim = MechanicalNeedle(np.eye(4), needle, TissueSpec(0.1, 0.3))
    sim.step(0.4, sim.kappa_max_per_mm, 30.0, 1.0)
    sim.step(2.0, 0.5 * sim.kappa_max_per_mm, 17.3, 1.0)
    return sim


def test_channel_sampling_kernel_matches_reference():
    ch = _bent_needle().channel
    q = np.concatenate([np.linspace(-1.0, ch.end_depth_mm + 1.0, 301), ch.depth_mm])
    for got, want in zip(ch.sample(q), ch.sample_reference(q), strict=True):
        assert np.allclose(got, want, rtol=0, atol=1e-12)


def test_rod_solve_kernel_matches_reference():
    sim = _bent_needle()
    args = (
        sim.channel,
        sim.guide,
        sim.gap_mm,
        sim.inserted_mm,
        sim.ei,
        sim.k,
        sim.unsupported_mm,
        (0.03, -0.05),
        0.7,
        (0.01, -0.02),
        3.0,
    )
    fast = solve_shaft(*args)
    slow = solve_shaft(*args, reference=True)
    scale = np.abs(slow.offsets_mm).max()
    assert scale > 1e-3
    assert np.allclose(fast.offsets_mm, slow.offsets_mm, rtol=0, atol=1e-10 * scale)
    assert np.allclose(fast.slopes, slow.slopes, rtol=0, atol=1e-10 * np.abs(slow.slopes).max())
    f = np.abs(slow.tissue_forces_n).max()
    assert f > 0 and np.allclose(fast.tissue_forces_n, slow.tissue_forces_n, atol=1e-10 * f)


def test_foundation_kernel_matches_reference():
    from needlekit.mechanics._kernels import foundation_kernel

    rng = np.random.default_rng(4)
    s = np.concatenate([np.linspace(0.0, 10.0, 11), 10.0 + np.cumsum(rng.uniform(0.05, 1.0, 60))])
    gap, support_end, k = 10.0, float(s[-1]) - 1.4, 0.02
    mid = 0.5 * (s[1:] + s[:-1])
    held = (mid > gap) & (mid < support_end)
    factors = rng.uniform(0.5, 1.5, 20)  # shorter than the depth: the last one beyond
    want = np.where(held, k * factors[np.clip((mid - gap).astype(int), 0, 19)], 0.0)
    assert np.array_equal(foundation_kernel(s, gap, support_end, k, factors), want)
    assert np.array_equal(foundation_kernel(s, gap, support_end, k, np.zeros(0)),
                          np.where(held, k, 0.0))  # fmt: skip


def test_node_positions_kernel_is_the_reference_to_the_bit():
    from needlekit.mechanics.shaft import node_positions, node_positions_reference

    rng = np.random.default_rng(4)
    cases = [(10.0, 45.3, (44.8, 40.3), 1.0), (0.0, 12.0, (11.5,), 1.0), (5.0, 0.0, (), 0.7),
             (10.0, 0.01, (9.0, 10.005), 1.0), (3.0, 7.0, (13.0 - 1e-10, 5.0, 20.0), 0.5),
             (2.5, 20.0, (12.5, 12.5), 1.0)]  # fmt: skip
    for _ in range(400):  # breaks on nodes, near nodes, near the tip, outside the rod
        gap, depth, h = rng.choice([0.0, rng.uniform(0, 20)]), rng.uniform(0, 80), rng.uniform(0.2, 2)
        tip = gap + depth
        breaks = [tip - rng.choice([0.0, 1e-10, rng.uniform(0, 3) * h]),
                  gap + h * rng.integers(0, 40) + rng.choice([0.0, rng.normal(0, 0.3 * h)]),
                  rng.uniform(-5, tip + 5)]  # fmt: skip
        cases.append((gap, depth, tuple(breaks[: rng.integers(0, 4)]), h))
    for gap, depth, breaks, h in cases:
        got, want = node_positions(gap, depth, breaks, h), node_positions_reference(gap, depth, breaks, h)
        assert got.dtype == want.dtype and np.array_equal(got, want), (gap, depth, breaks, h)


def test_reference_kernel_is_the_numpy_reference_to_the_bit():
    from needlekit.mechanics.shaft import _reference, _reference_numpy, node_positions

    sim = _bent_needle()
    for h in (0.3, 0.7, 1.0):
        s = node_positions(sim.gap_mm, sim.inserted_mm, (sim.gap_mm + 30.0, sim.gap_mm + 44.1), h)
        for a, b in zip(_reference(sim.channel, sim.guide, s, sim.gap_mm),
                        _reference_numpy(sim.channel, sim.guide, s, sim.gap_mm), strict=True):  # fmt: skip
            assert np.array_equal(a, b)


def test_offsets_kernel_is_the_numpy_reference_to_the_bit():
    from needlekit.mechanics._kernels import offsets_kernel
    from needlekit.mechanics.shaft import _offsets_numpy, _reference, node_positions

    sim = _bent_needle()
    tip = sim.gap_mm + sim.inserted_mm
    s = node_positions(sim.gap_mm, sim.inserted_mm, (tip - 0.8, tip - 3.0), 0.7)
    pos, tan, ex, ey = _reference(sim.channel, sim.guide, s, sim.gap_mm)
    for curv, length in (((0.0, 0.0), 0.0), ((0.01, -0.02), 3.0), ((0.05, 0.0), tip + 5.0)):
        fast = offsets_kernel(s, pos, tan, ex, ey, *curv, length, tip - length)
        slow = _offsets_numpy(s, pos, tan, ex, ey, curv, length, tip - length)
        assert all(np.array_equal(a, b) for a, b in zip(fast, slow, strict=True))
        assert length == 0.0 or np.any(slow[1][:, 3] != _offsets_numpy(s, pos, tan, ex, ey, (0, 0), 0.0, tip)[1][:, 3])
