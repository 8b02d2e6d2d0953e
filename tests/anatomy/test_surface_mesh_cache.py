"""Surface meshes kept by content (anatomy.summary): the same bits with and without the
cache, a changed field never answered from an old mesh, and the memory bound held."""

import json

import numpy as np
import pytest

import needlekit.anatomy.summary as summary
from needlekit.anatomy.fields import ComplementField, LazyField, TransformedField, union
from needlekit.anatomy.phantoms._atom_kernels import round_cone
from needlekit.anatomy.phantoms._atoms import AtomField
from needlekit.anatomy.primitives import Capsule, Cylinder, Ellipsoid, Sphere
from needlekit.anatomy.summary import field_content_key, surface_mesh
from needlekit.anatomy.voxel import VoxelSDF, grid_for_bounds

#: The toy scene's shapes (examples/toy.yaml) and its box.
TOY_BOX = np.array([[-80.0, -60.0, -100.0], [80.0, 60.0, 100.0]])
CROP = np.array([[-15.0, -30.0, -15.0], [35.0, 45.0, 55.0]])


def _toy():
    return [
        Ellipsoid([80, 60, 100]),
        Capsule([-40, 10, -10], [40, 10, 5], 4),
        Cylinder([0, -20, -90], [0, -20, 90], 8),
        Sphere([20, 30, 40], 7),
    ]


def _grid(scale_z: float = 0.8) -> VoxelSDF:
    affine, shape = grid_for_bounds([[-12, -12, -12], [12, 12, 12]], 0.5, 3.0)
    return VoxelSDF.from_function(
        lambda p: np.linalg.norm(p * [1.0, 1.3, scale_z], axis=1) - 8.0, affine, shape
    )


@pytest.fixture(autouse=True)
def _fresh_cache():
    summary._MESHES.clear()
    yield
    summary._MESHES.clear()


def _uncached(monkeypatch, field, **kw):
    with monkeypatch.context() as m:
        m.setattr(summary, "MESH_CACHE_BYTES", 0)
        return surface_mesh(field, **kw)


def _same(a, b):
    for x, y in zip(a, b, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)


@pytest.mark.parametrize("crop", [None, CROP])
def test_meshes_are_the_same_bits_cold_warm_rebuilt_and_uncached(monkeypatch, crop):
    kw = {"bounds": TOY_BOX, "crop": crop, "max_cells": 64}
    for field, again in zip(_toy(), _toy(), strict=True):
        off = _uncached(monkeypatch, field, **kw)
        cold = surface_mesh(field, **kw)
        warm = surface_mesh(again, **kw)  # another object, the same shape: from the cache
        _same(off, cold)
        _same(off, warm)
        assert len(off[1]) > 0
    assert summary._MESHES.hits == 4 and summary._MESHES.misses == 4


def test_voxel_and_composite_meshes_are_the_same_bits(monkeypatch):
    grid = _grid()
    sphere = Sphere([1, 2, 3], 9.0)
    pose = np.eye(4)
    pose[:3, 3] = [4, -3, 2]
    box = np.array([[-20.0] * 3, [20.0] * 3])
    cases = [
        (grid, {}),
        (grid, {"crop": np.array([[-3.0, -5, -4], [9.0, 6, 7]])}),
        (grid, {"max_cells": 20}),
        (grid.inflated(1.0), {"max_cells": 30}),
        (union(sphere, Capsule([0, 0, 0], [10, 0, 0], 3)), {"max_cells": 40}),
        (TransformedField(sphere, pose), {"max_cells": 40}),
        (ComplementField(sphere), {"bounds": box, "max_cells": 40}),
        (AtomField([round_cone([0, 0, 0], [0, 0, 30], 4.0, 2.0)]), {"max_cells": 40}),
    ]
    for field, kw in cases:
        off = _uncached(monkeypatch, field, **kw)
        _same(off, surface_mesh(field, **kw))
        _same(off, surface_mesh(field, **kw))
    assert summary._MESHES.hits == len(cases)


def test_scene_figure_json_is_the_same_with_and_without_the_cache(monkeypatch):
    from needlekit.anatomy.scene import Role, Scene, Structure
    from needlekit.report.scene3d import scene_figure

    roles = [Role.ALLOWED_REGION, Role.OBSTACLE, Role.OBSTACLE, Role.TARGET]
    names = ["lung", "vessel", "airway", "nodule"]

    def figure():
        scene = Scene([Structure(n, r, f) for n, r, f in zip(names, roles, _toy(), strict=True)])
        path = np.array([[0, -12, 0], [5, 5, 10], [12, 20, 28], [20, 30, 40.0]])
        return scene_figure(scene, paths_mm=[path], focus_mm=path, max_cells=48).to_json()

    with monkeypatch.context() as m:
        m.setattr(summary, "MESH_CACHE_BYTES", 0)
        off = figure()
    cold, warm = figure(), figure()
    assert summary._MESHES.hits == 4
    assert off == cold == warm
    assert len(json.loads(off)["data"]) == 5  # four surfaces and the path


def test_a_changed_field_gets_its_own_mesh():
    # a stale hit would put the second sphere's vertices on the first one's radius
    kw = {"max_cells": 40, "bounds": TOY_BOX}
    h = 2 * 12.0 / 40  # the sampling step over the larger sphere's box, at most
    for radius in (7.0, 9.0, 7.0):
        verts, _ = surface_mesh(Sphere([20, 30, 40], radius), **kw)
        r = np.linalg.norm(verts - [20, 30, 40], axis=1)
        assert np.all(np.abs(r - radius) < h), radius
    assert summary._MESHES.hits == 1  # the third is the first again
    # changed in place: the key follows the contents
    sphere = Sphere([20, 30, 40], 7.0)
    before, _ = surface_mesh(sphere, **kw)
    sphere.center_mm[:] = [0.0, 0.0, 0.0]
    after, _ = surface_mesh(sphere, **kw)
    assert np.allclose(after.mean(axis=0), [0, 0, 0], atol=0.1)
    assert np.allclose(before.mean(axis=0), [20, 30, 40], atol=0.1)
    # a grid with other values, an atom moved, a margin changed
    a, b = surface_mesh(_grid(0.8)), surface_mesh(_grid(0.7))
    assert np.ptp(a[0][:, 2]) < np.ptp(b[0][:, 2])  # the second is longer along z
    c1 = surface_mesh(AtomField([round_cone([0, 0, 0], [0, 0, 30], 4.0, 2.0)]), max_cells=40)
    c2 = surface_mesh(AtomField([round_cone([0, 0, 0], [0, 0, 40], 4.0, 2.0)]), max_cells=40)
    assert c1[0][:, 2].max() == pytest.approx(32.0, abs=0.5)
    assert c2[0][:, 2].max() == pytest.approx(42.0, abs=0.5)
    o1 = surface_mesh(Sphere([0, 0, 0], 5.0).inflated(1.0), max_cells=40)
    o2 = surface_mesh(Sphere([0, 0, 0], 5.0).inflated(2.0), max_cells=40)
    assert np.linalg.norm(o1[0], axis=1).mean() == pytest.approx(6.0, abs=0.1)
    assert np.linalg.norm(o2[0], axis=1).mean() == pytest.approx(7.0, abs=0.1)
    assert summary._MESHES.hits == 2  # and the sphere before it moved, a radius 7 one again


def test_the_box_and_the_resolution_are_in_the_key(monkeypatch):
    # the same field asked for over other boxes, crops and resolutions: each its own mesh
    lung, grid = _toy()[0], _grid()
    asks = [
        (lung, {"bounds": TOY_BOX}),
        (lung, {"bounds": TOY_BOX, "crop": CROP}),
        (lung, {"bounds": TOY_BOX, "crop": CROP + 5.0}),
        (lung, {"bounds": TOY_BOX, "max_cells": 50}),
        (lung, {"bounds": TOY_BOX * 1.1}),
        (lung, {}),  # its own box, the same as TOY_BOX: the first mesh again
        (grid, {}),
        (grid, {"crop": np.array([[-3.0, -5, -4], [9.0, 6, 7]])}),
        (grid, {"max_cells": 20}),
    ]
    meshes = [surface_mesh(f, **kw) for f, kw in asks]
    assert summary._MESHES.hits == 1
    for (f, kw), mesh in zip(asks, meshes, strict=True):
        _same(_uncached(monkeypatch, f, **kw), mesh)
    counts = [len(m[1]) for m in meshes]
    assert len(set(counts[:5])) == 5 and len(set(counts[6:])) == 3


def test_keys_by_content_and_none_without_a_cheap_one():
    a, b = _toy(), _toy()
    assert [field_content_key(f) for f in a] == [field_content_key(f) for f in b]
    assert len({field_content_key(f) for f in a}) == 4
    assert field_content_key(Sphere([0, 0, 0], 1.0)) != field_content_key(Sphere([0, 0, 0], 2.0))
    pose = np.eye(4)
    pose[:3, 3] = [1, 0, 0]
    assert field_content_key(Sphere([0, 0, 0], 1.0)) != field_content_key(
        Sphere([0, 0, 0], 1.0, pose)
    )
    assert field_content_key(_grid()) == field_content_key(_grid())
    assert field_content_key(_grid(0.8)) != field_content_key(_grid(0.7))
    s = Sphere([0, 0, 0], 1.0)
    assert field_content_key(s.inflated(1.0)) != field_content_key(s.inflated(2.0))
    assert field_content_key(union(s, a[1])) != field_content_key(union(a[1], s))

    class Shifted(Sphere):  # a subclass may answer differently: no key
        def _local_distance(self, q):
            return super()._local_distance(q) - 1.0

    lazy = LazyField(lambda: s, "sphere")
    assert field_content_key(Shifted([0, 0, 0], 1.0)) is None
    assert field_content_key(lazy) is None
    assert field_content_key(union(s, lazy)) is None
    # a field without a key is meshed each time, and right
    assert summary._MESHES.misses == 0
    v, _ = surface_mesh(Shifted([0, 0, 0], 4.0), max_cells=40)
    v2, _ = surface_mesh(Shifted([0, 0, 0], 4.0), max_cells=40)
    assert summary._MESHES.hits == 0 and np.array_equal(v, v2)
    assert np.linalg.norm(v, axis=1).mean() == pytest.approx(5.0, abs=0.1)


def test_callers_get_their_own_copies():
    sphere = Sphere([0, 0, 0], 5.0)
    v1, f1 = surface_mesh(sphere, max_cells=30)
    keep = v1.copy(), f1.copy()
    v1[:] = 0.0
    f1[:] = 0
    v2, f2 = surface_mesh(sphere, max_cells=30)
    assert summary._MESHES.hits == 1
    _same(keep, (v2, f2))
    assert v2.flags.writeable and f2.flags.writeable


def test_memory_bound_drops_the_least_recently_used(monkeypatch):
    spheres = [Sphere([0, 0, 0], r) for r in (4.0, 5.0, 6.0)]
    sizes = [sum(a.nbytes for a in surface_mesh(s, max_cells=30)) for s in spheres]
    summary._MESHES.clear()
    monkeypatch.setattr(summary, "MESH_CACHE_BYTES", sizes[1] + sizes[2])
    for s in spheres:
        surface_mesh(s, max_cells=30)
    assert summary._MESHES._bytes <= summary.MESH_CACHE_BYTES
    surface_mesh(spheres[2], max_cells=30)
    surface_mesh(spheres[1], max_cells=30)
    assert summary._MESHES.hits == 2
    surface_mesh(spheres[0], max_cells=30)  # dropped for the two after it
    assert summary._MESHES.hits == 2
    monkeypatch.setattr(summary, "MESH_CACHE_BYTES", 0)  # nothing kept
    summary._MESHES.clear()
    surface_mesh(spheres[0], max_cells=30)
    surface_mesh(spheres[0], max_cells=30)
    assert summary._MESHES.hits == 0 and summary._MESHES._bytes == 0
