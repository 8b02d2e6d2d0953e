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
