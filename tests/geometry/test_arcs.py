"""Constant-curvature arcs: closed form vs the SE(3) exponential, numba vs numpy reference."""

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import (
    arc_transform,
    propagate_arcs,
    propagate_arcs_reference,
    sample_arcs,
    sample_arcs_reference,
    samples_for_spacing,
)
from needlekit.geometry.se3 import make_pose, se3_exp
from needlekit.geometry.so3 import rot_z


def _random_arcs(rng, n):
    spin = rng.uniform(-np.pi, np.pi, n)
    kappa = rng.uniform(-0.05, 0.05, n)
    kappa[: n // 10] = 0.0  # straight segments
    kappa[n // 10 : n // 5] = rng.uniform(-1e-9, 1e-9, n // 10)  # nearly straight
    length = rng.uniform(0, 200, n)
    length[:3] = 0.0
    return spin, kappa, length


def _random_poses(rng, n):
    xi = np.concatenate([rng.normal(0, 100, (n, 3)), rng.normal(0, 1, (n, 3))], axis=1)
    return se3_exp(xi)


def test_arc_transform_is_spin_then_exponential_of_insertion_twist():
    rng = np.random.default_rng(0)
    spin, kappa, length = _random_arcs(rng, 500)
    got = arc_transform(spin, kappa, length)
    for g, s, k, ell in zip(got, spin, kappa, length, strict=True):
        ref = make_pose(rot_z(s)) @ se3_exp([0, 0, ell, k * ell, 0, 0])
        assert np.allclose(g, ref, atol=1e-11)


def test_quarter_circle_closed_form():
    g = arc_transform(0.0, 1 / 50, 25 * np.pi)
    assert np.allclose(g[:3, 3], [0.0, -50.0, 50.0], atol=1e-12)
    assert np.allclose(g[:3, 2], [0.0, -1.0, 0.0], atol=1e-15)


def test_propagate_kernel_matches_reference():
    rng = np.random.default_rng(1)
    spin, kappa, length = _random_arcs(rng, 2000)
    poses = _random_poses(rng, 2000)
    assert np.allclose(
        propagate_arcs(poses, spin, kappa, length),
        propagate_arcs_reference(poses, spin, kappa, length),
        atol=1e-11,
    )
    # one pose shared by all arcs, and a single arc
    one = poses[0]
    assert np.allclose(
        propagate_arcs(one, spin, kappa, length), propagate_arcs_reference(one, spin, kappa, length)
    )
    assert propagate_arcs(one, 0.1, 0.01, 5.0).shape == (4, 4)


def test_sample_kernel_matches_reference_and_spacing():
    rng = np.random.default_rng(2)
    spin, kappa, length = _random_arcs(rng, 500)
    poses = _random_poses(rng, 500)
    got = sample_arcs(poses, spin, kappa, length, 33)
    assert np.allclose(got, sample_arcs_reference(poses, spin, kappa, length, 33), atol=1e-11)
    # consecutive samples are equally spaced in arc length; chords never exceed it
    chord = np.linalg.norm(np.diff(got, axis=1), axis=2)
    assert np.all(chord <= length[:, None] / 32 + 1e-9)
    # ends: start point and propagate_arcs' end point
    ends = propagate_arcs(poses, spin, kappa, length)
    assert np.allclose(got[:, 0], poses[:, :3, 3])
    assert np.allclose(got[:, -1], ends[:, :3, 3], atol=1e-11)


def test_samples_for_spacing():
    assert samples_for_spacing(10.0, 0.5) == 21
    assert samples_for_spacing(10.1, 0.5) == 22
    assert samples_for_spacing(0.0, 0.5) == 2
    with pytest.raises(InvalidInputError, match="spacing_mm"):
        samples_for_spacing(1.0, 0.0)


def test_bad_arcs_are_refused():
    with pytest.raises(InvalidInputError, match="length_mm"):
        arc_transform(0.0, 0.01, -1.0)
    with pytest.raises(InvalidInputError, match="kappa_per_mm"):
        propagate_arcs(np.eye(4), 0.0, np.nan, 1.0)
    with pytest.raises(InvalidInputError, match="n_samples"):
        sample_arcs(np.eye(4), 0.0, 0.0, 1.0, 1)
    with pytest.raises(InvalidInputError, match="do not match"):
        propagate_arcs(np.stack([np.eye(4)] * 3), np.zeros(2), 0.0, 1.0)
    with pytest.raises(InvalidInputError, match="world_T_tip"):
        propagate_arcs(np.full((4, 4), np.nan), 0.0, 0.0, 1.0)
