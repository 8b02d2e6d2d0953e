"""Scene queries, conservative clearance along segments and arcs, composite fields."""

import numpy as np
import pytest

from needlekit.anatomy.clearance import arc_clearance, segment_clearance
from needlekit.anatomy.fields import ComplementField, LazyField, TransformedField, union
from needlekit.anatomy.primitives import Capsule, HalfSpace, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import sample_arcs
from needlekit.geometry.se3 import se3_exp


@pytest.fixture
def scene():
    return Scene(
        [
            Structure("lung", Role.ALLOWED_REGION, Sphere([0, 0, 0], 100.0)),
            Structure("vessel", Role.OBSTACLE, Capsule([-50, 20, 0], [50, 20, 0], 4.0)),
            Structure("airway", "obstacle", Sphere([0, -40, 0], 10.0)),
            Structure("nodule", Role.TARGET, Sphere([0, 0, 60], 8.0)),
            Structure("skin", Role.ENTRY_SURFACE, HalfSpace([0, 0, 120], [0, 0, 1])),
        ],
        name="toy",
    )


def test_roles_and_access(scene):
    assert scene.names == ["lung", "vessel", "airway", "nodule", "skin"]
    assert [s.name for s in scene.by_role("obstacle")] == ["vessel", "airway"]
    assert scene["nodule"].role is Role.TARGET and "skin" in scene and len(scene) == 5
    with pytest.raises(InvalidInputError, match="no structure named 'liver'"):
        scene["liver"]
    with pytest.raises(InvalidInputError, match="role"):
        Structure("x", "wall", Sphere([0, 0, 0], 1.0))
    with pytest.raises(InvalidInputError, match="duplicate"):
        Scene([Structure("a", "target", Sphere([0, 0, 0], 1.0))] * 2)


def test_signed_distances_and_clearance_against_closed_forms(scene):
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 95.0], [0.0, 20.0, 0.0], [0.0, 0.0, 150.0]])
    d = scene.signed_distance(p)
    assert np.allclose(d["lung"], [-100, -5, -80, 50])
    assert np.allclose(d["vessel"], [16, np.hypot(20, 95) - 4, -4, np.hypot(20, 150) - 4])
    # clearance: nearest obstacle, or leaving the lung
    expected = np.minimum.reduce([100 - np.linalg.norm(p, axis=1), d["vessel"], d["airway"]])
    assert np.allclose(scene.clearance(p), expected)
    assert np.allclose(scene.clearance(p, margin_mm=1.5), expected - 1.5)
    # excluding an obstacle
    far = scene.obstacle_field(exclude=["airway"]).signed_distance([0.0, -40.0, 0.0])
    assert far == pytest.approx(56.0)


def test_normals_are_outward_unit_vectors(scene):
    n = scene.normal([[0.0, 0.0, 99.0], [0.0, 20.0, 5.0]], "lung")
    assert np.allclose(n[0], [0, 0, 1], atol=1e-6)
    n = scene.normal([0.0, 20.0, 5.0], "vessel")
    assert np.allclose(n, [0, 0, 1], atol=1e-6)


def test_segment_clearance_is_conservative_even_for_thin_obstacles():
    # a 0.05 mm thin wire crosses the segment between two samples 2 mm apart
    wire = Capsule([0.0, -10.0, 0.0], [0.0, 10.0, 0.0], 0.05)
    c = segment_clearance(wire, [-3.0, 0.0, 0.0], [3.0, 0.0, 0.0], spacing_mm=2.0)
    assert c.sampled_min_mm[0] > 0.9  # the samples alone miss the wire
    assert c.clearance_mm[0] <= -0.05 + 1e-12  # the bound does not
    # dense brute force: the bound never exceeds the true minimum clearance
    rng = np.random.default_rng(0)
    field = union(Sphere([0, 0, 0], 5.0), Capsule([0, -30, 10], [0, 30, 10], 0.3))
    a = rng.uniform(-40, 40, (300, 3))
    b = a + rng.normal(0, 30, (300, 3))
    c = segment_clearance(field, a, b, spacing_mm=1.5)
    t = np.linspace(0, 1, 4001)
    dense = field.signed_distance((a[:, None] + t[None, :, None] * (b - a)[:, None]).reshape(-1, 3))
    truth = dense.reshape(300, -1).min(axis=1)
    assert np.all(c.clearance_mm <= truth + 1e-9)
    assert np.all(c.certified_mm <= truth + 1e-9)
    assert np.all(truth - c.clearance_mm <= 0.75 + 1e-9)  # at most half the gap looser


def test_arc_clearance_matches_dense_sampling():
    rng = np.random.default_rng(1)
    field = union(Sphere([0, -20, 40], 6.0), Capsule([-30, 0, 70], [30, 0, 70], 1.0))
    poses = se3_exp(np.column_stack([rng.normal(0, 5, (50, 3)), rng.normal(0, 0.3, (50, 3))]))
    spin, kappa, length = (
        rng.uniform(-np.pi, np.pi, 50),
        rng.uniform(0, 0.03, 50),
        rng.uniform(10, 100, 50),
    )
    c = arc_clearance(field, poses, spin, kappa, length, spacing_mm=1.0)
    dense = sample_arcs(poses, spin, kappa, length, 3001)
    truth = field.signed_distance(dense.reshape(-1, 3)).reshape(50, -1).min(axis=1)
    assert np.all(c.clearance_mm <= truth + 1e-9)
    assert np.all(truth - c.clearance_mm <= 0.5 + 1e-9)
    one = arc_clearance(field, np.eye(4), 0.0, 0.01, 50.0)
    assert one.clearance_mm.shape == (1,)


def test_scene_path_clearance_uses_margin(scene):
    c0 = scene.segment_clearance([0, 0, 0], [0, 0, 50])
    c1 = scene.segment_clearance([0, 0, 0], [0, 0, 50], margin_mm=2.0)
    assert c1.clearance_mm[0] == pytest.approx(c0.clearance_mm[0] - 2.0)
    a = scene.arc_clearance(np.eye(4), 0.0, 0.0, 50.0)
    assert a.clearance_mm[0] == pytest.approx(c0.clearance_mm[0])


def test_composites():
    s = Sphere([0, 0, 0], 10.0)
    p = np.array([[0.0, 0.0, 25.0], [3.0, 0.0, 0.0]])
    assert np.allclose(ComplementField(s).signed_distance(p), -s.signed_distance(p))
    assert np.allclose(s.inflated(2.0).signed_distance(p), s.signed_distance(p) - 2.0)
    g = se3_exp([5.0, -3.0, 2.0, 0.3, 0.2, -0.1])
    moved = TransformedField(Capsule([0, 0, 0], [0, 0, 20], 2.0), g)
    local = (p - g[:3, 3]) @ g[:3, :3]
    assert np.allclose(
        moved.signed_distance(p), Capsule([0, 0, 0], [0, 0, 20], 2.0).signed_distance(local)
    )
    calls = []
    lazy = LazyField(lambda: calls.append(1) or s, "ball")
    assert not lazy.built and "not built" in repr(lazy)
    assert np.allclose(lazy.signed_distance(p), s.signed_distance(p)) and lazy.built
    lazy.signed_distance(p)
    assert calls == [1]
    with pytest.raises(InvalidInputError, match="margin_mm"):
        s.inflated(-1.0)
    with pytest.raises(InvalidInputError, match="DistanceField"):
        union(s, "not a field")


def test_precomputed_obstacle_field_is_used(scene):
    combined = scene.obstacle_field()
    fast = Scene(list(scene.structures), obstacle_field=combined)
    assert fast.obstacle_field() is combined
    p = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(fast.clearance(p, 1.0), scene.clearance(p, 1.0))


def test_a_target_reaching_past_the_allowed_region_is_not_an_obstacle():
    # a tumour that the organ's segmentation leaves out (as Med-RAD's liver masks do)
    scene = Scene(
        [
            Structure("liver", Role.ALLOWED_REGION, Sphere([0, 0, 0], 50.0)),
            Structure("tumour", Role.TARGET, Sphere([0, 0, 55.0], 10.0)),
        ]
    )
    inside_tumour_outside_liver = np.array([0.0, 0.0, 58.0])
    assert scene.clearance(inside_tumour_outside_liver) > 0
    assert scene.clearance([0.0, 0.0, 80.0]) < 0  # outside both
