"""The condensed compliance against full solves, breathing, the runtime's loads and
inverse map, the cache, and bad masks."""

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.execute.breathing import Breathing
from needlekit.tissue.compliance import (
    compute_compliance,
    interpolation,
    precompute,
    resample_polyline,
)
from needlekit.tissue.fem import LUNG, ElasticProblem, Material, organ_boundary
from needlekit.tissue.meshing import mesh_mask
from needlekit.tissue.runtime import DeformingTissue

AFFINE = np.diag([1.0, 1.0, 1.0, 1.0])
CORRIDOR = resample_polyline([[4.0, 11.0, 10.0], [18.0, 12.0, 13.0]], 1.5)
TRACKED = np.array([[19.0, 12.5, 13.5], [15.0, 8.0, 12.0], [9.0, 15.0, 9.0]])
LABELS = ("target", "vessels", "bronchialTree")


def _box(n=24):
    mask = np.zeros((n, n, n), bool)
    mask[1:-1, 1:-1, 1:-1] = True
    return mask


@pytest.fixture(scope="module")
def lung_problem():
    mesh = mesh_mask(_box(), AFFINE, cell_mm=2.75)
    return ElasticProblem(mesh, LUNG, organ_boundary(mesh, "lung"))


@pytest.fixture(scope="module")
def lung_compliance(lung_problem):
    return compute_compliance(lung_problem, CORRIDOR, TRACKED, LABELS)


def test_compliance_equals_full_solve(lung_problem, lung_compliance):
    comp, problem = lung_compliance, lung_problem
    w_c, _ = interpolation(problem.mesh, CORRIDOR)
    w_all, inside = interpolation(problem.mesh, np.concatenate([CORRIDOR, TRACKED]))
    assert inside.all()
    rng = np.random.default_rng(3)
    f = rng.normal(0, 0.05, (len(CORRIDOR), 3))
    d = np.array([0.5, -1.0, 4.0])
    full = problem.solve(w_c.T @ f.ravel(), problem.breathing_held(d))
    expected = w_all @ full.ravel()
    got = comp.C @ f.ravel() + comp.B @ d
    assert np.max(np.abs(got - expected)) <= 1e-9 * np.max(np.abs(expected))
    tissue = DeformingTissue(comp)
    tissue.apply(CORRIDOR, f, breathing=d)  # loads on the corridor points themselves
    assert np.allclose(tissue.displacement_at("all").ravel(), expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    assert np.max(np.abs(tissue.mesh_displacement() - full)) <= 1e-9 * np.abs(full).max()


def test_a_point_within_a_cell_of_the_held_surface_is_pinned(lung_problem):
    mesh = lung_problem.mesh
    held = np.zeros(mesh.n_nodes, bool)
    held[lung_problem.boundary.held] = True
    surface_tet = np.flatnonzero(held[mesh.tets].all(axis=1))[0]
    inner = mesh.nodes_mm[mesh.tets[surface_tet]].mean(axis=0)
    comp = compute_compliance(lung_problem, CORRIDOR, np.vstack([TRACKED, inner]), (*LABELS, "vessels"))
    assert comp.pinned().tolist() == [False, False, False, True]
    # the oracle: a full solve under loads along the corridor moves the others, never it
    w_c, _ = interpolation(mesh, CORRIDOR)
    w_t, _ = interpolation(mesh, np.vstack([TRACKED, inner]))
    f = np.random.default_rng(5).normal(0, 0.05, (len(CORRIDOR), 3))
    moved = (w_t @ lung_problem.solve(w_c.T @ f.ravel()).ravel()).reshape(-1, 3)
    assert np.all(np.linalg.norm(moved[:3], axis=1) > 1e-3) and np.all(moved[3] == 0.0)


def test_lung_breathing_weights_rise_from_apex_to_base(lung_problem):
    b = lung_problem.boundary
    s = lung_problem.mesh.nodes_mm[b.held, 2]
    assert np.allclose(b.weight[s == s.max()], 0.0) and np.allclose(b.weight[s == s.min()], 1.0)


def test_uniform_boundary_translation_is_the_rigid_breathing_trace():
    mesh = mesh_mask(_box(), AFFINE, cell_mm=2.75)
    problem = ElasticProblem(mesh, LUNG, organ_boundary(mesh, "lung", mode="uniform"))
    comp = compute_compliance(problem, CORRIDOR, TRACKED, LABELS)
    n = len(CORRIDOR) + len(TRACKED)
    assert np.max(np.abs(comp.B - np.tile(np.eye(3), (n, 1)))) < 1e-12
    trace = Breathing(amplitude_mm=5.0).trace(np.random.default_rng(0), 10.0)
    tissue = DeformingTissue(comp)
    for t in (0.0, 1.3, 2.0, 5.7):
        tissue.apply(np.zeros((0, 3)), np.zeros((0, 3)), breathing=trace.actual(t))
        assert np.max(np.abs(tissue.target_mm() - (TRACKED[0] + trace.actual(t)))) < 1e-12
        assert np.max(np.abs(tissue.mesh_displacement() - trace.actual(t))) < 1e-12


def test_liver_free_surface_makes_breathing_a_translation():
    mesh = mesh_mask(_box(), AFFINE, cell_mm=2.75)
    problem = ElasticProblem(mesh, Material(4.7, 0.45), organ_boundary(mesh, "liver"))
    held_s = mesh.nodes_mm[problem.boundary.held, 2]
    assert np.allclose(held_s, mesh.nodes_mm[:, 2].max())  # the superior face
    comp = compute_compliance(problem, CORRIDOR, TRACKED, LABELS)
    assert np.max(np.abs(comp.B - np.tile(np.eye(3), (len(CORRIDOR) + 3, 1)))) < 1e-9


def test_loads_shared_along_the_corridor(lung_compliance):
    tissue = DeformingTissue(lung_compliance)
    f = np.array([[0.0, 0.1, 0.0]])
    on = tissue.corridor_forces(CORRIDOR[3:4], f)
    assert np.allclose(on[3], f[0]) and np.allclose(np.delete(on, 3, axis=0), 0)
    axis = CORRIDOR[4] - CORRIDOR[3]
    off = np.cross(axis, [0.0, 0.0, 1.0])
    mid = 0.25 * CORRIDOR[3] + 0.75 * CORRIDOR[4] + 0.5 * off / np.linalg.norm(off)  # beside it
    shared = tissue.corridor_forces(mid[None], f)
    assert np.allclose(shared[3], 0.25 * f[0]) and np.allclose(shared[4], 0.75 * f[0])
    assert np.allclose(shared.sum(axis=0), f[0])
    with pytest.raises(InvalidInputError, match="points_mm"):
        tissue.corridor_forces(CORRIDOR[3:4] + [0.0, 0.0, 20.0], f)
    with pytest.raises(InvalidInputError, match="breathing"):
        tissue.apply(CORRIDOR[:1], f, breathing=[0.0, float("nan"), 0.0])


def test_to_rest_inverts_the_deformation(lung_compliance):
    tissue = DeformingTissue(lung_compliance)
    rng = np.random.default_rng(5)
    tissue.apply(CORRIDOR, rng.normal(0, 0.02, (len(CORRIDOR), 3)), breathing=[0.0, 0.0, -2.0])
    rest = np.concatenate([TRACKED, CORRIDOR[::3] + [0.3, -0.4, 0.2]])
    world = rest + tissue.displacement_field(rest)
    assert np.max(np.abs(world - rest)) > 0.1  # it did move
    assert np.max(np.abs(tissue.to_rest(world) - rest)) < 1e-6
    # the tracked points' interpolated displacement is the condensed one
    assert np.allclose(tissue.displacement_field(TRACKED), tissue.tracked_displacement_mm, atol=1e-12)


def test_a_point_at_a_time_answers_as_the_search_does(lung_compliance):
    # a tip's points one at a time (remembered tetrahedra, then the search when none holds
    # it) against the same points in one batch (the search for each): the same bits, on a
    # walk that crosses cells, revisits them and lands on vertices and faces
    tissue = DeformingTissue(lung_compliance)
    rng = np.random.default_rng(11)
    tissue.apply(CORRIDOR, rng.normal(0, 0.02, (len(CORRIDOR), 3)), breathing=[0.5, 0.0, -2.0])
    mesh = lung_compliance.mesh
    walk = CORRIDOR[0] + np.cumsum(rng.normal(0, 0.4, (300, 3)), axis=0)
    walk = np.clip(walk, mesh.nodes_mm.min(axis=0) + 0.5, mesh.nodes_mm.max(axis=0) - 0.5)
    on_mesh = np.concatenate([mesh.nodes_mm[mesh.tets[7]], mesh.nodes_mm[mesh.tets[7, :3]].mean(axis=0)[None]])
    pts = np.concatenate([walk, walk[::-7], on_mesh])
    for loads in (True, False):
        one = np.concatenate([tissue.displacement_field(p[None], loads) for p in pts])
        assert np.array_equal(one, tissue.displacement_field(pts, loads))
    d = np.array([0.0, 1.0, -3.0])
    one = np.concatenate([tissue.breathing_field(p[None], d) for p in pts])
    assert np.array_equal(one, tissue.breathing_field(pts, d))


def test_precompute_cached_cold_then_warm(tmp_path):
    args = (_box(), AFFINE, "lung", CORRIDOR, TRACKED, LABELS)
    cold = precompute(*args, cell_mm=2.75, cache_dir=tmp_path)
    warm = precompute(*args, cell_mm=2.75, cache_dir=tmp_path)
    assert "mesh_s" in cold.info["timings_s"] and "cache_load_s" in warm.info["timings_s"]
    for name in ("C", "B", "G", "H"):
        assert np.array_equal(getattr(cold, name), getattr(warm, name))
    assert np.array_equal(cold.mesh.tets, warm.mesh.tets) and warm.tracked_labels == LABELS
    other = precompute(*args, cell_mm=2.75, cache_dir=tmp_path, material=Material(2.0, 0.43))
    assert "mesh_s" in other.info["timings_s"]  # another material: another entry
    assert np.allclose(other.C, cold.C / 2.0, rtol=1e-9, atol=0)  # compliance ~ 1 / E


def test_bad_masks_name_the_field():
    with pytest.raises(InvalidInputError, match=r"^mask: .*empty"):
        mesh_mask(np.zeros((10, 10, 10), bool), AFFINE)
    thin = np.zeros((40, 40, 40), bool)
    thin[:, :, 20] = True  # one voxel thick
    with pytest.raises(InvalidInputError, match=r"^mask: "):
        mesh_mask(thin, AFFINE, cell_mm=2.0)
    few = np.zeros((40, 40, 40), bool)
    few[:3, :3, :3] = True
    with pytest.raises(InvalidInputError, match=r"^mask: "):
        mesh_mask(few, AFFINE)
    with pytest.raises(InvalidInputError, match=r"^mask: "):
        mesh_mask(np.ones((4, 4), bool), AFFINE)
    with pytest.raises(InvalidInputError, match=r"^mask: "):
        precompute(np.zeros((10, 10, 10), bool), AFFINE, "lung", CORRIDOR, use_cache=False)
    with pytest.raises(InvalidInputError, match=r"^organ: "):
        precompute(_box(), AFFINE, "heart", CORRIDOR, use_cache=False)


@pytest.mark.slow
@pytest.mark.realdata
def test_medrad_lung1_compliance_equals_full_solve(medrad_dir, tmp_path):
    from needlekit.io.medrad_paths import patient_folder
    from needlekit.io.poses import read_point_txt, read_pose_txt
    from needlekit.io.volumes import read_mask

    folder = patient_folder("lung", 1, medrad_dir)
    m = read_mask(folder / "pleuralBoundary.nii.gz")
    target = read_point_txt(folder / "target.txt")
    start = read_pose_txt(folder / "start1.txt")[:3, 3]
    corridor = resample_polyline([start, target], 2.0)
    mesh = mesh_mask(m.data, m.affine, seed_mm=target)
    assert mesh.n_tets >= 50_000
    problem = ElasticProblem(mesh, LUNG, organ_boundary(mesh, "lung"))
    comp = compute_compliance(problem, corridor, target[None], ("target",))
    w_c, inside = interpolation(mesh, corridor)
    assert inside.sum() >= len(corridor) - 2  # the start lies on the airway wall
    f = np.random.default_rng(0).normal(0, 0.05, (len(corridor), 3))
    d = np.array([0.0, 0.0, -5.0])
    w_all, _ = interpolation(mesh, np.concatenate([corridor, target[None]]))
    expected = w_all @ problem.solve(w_c.T @ f.ravel(), problem.breathing_held(d)).ravel()
    got = comp.C @ f.ravel() + comp.B @ d
    assert np.max(np.abs(got - expected)) <= 1e-9 * np.abs(expected).max()


def test_sliding_surface_holds_only_the_normal():
    from needlekit.tissue.fem import Boundary

    mesh = mesh_mask(_box(), AFFINE, cell_mm=2.75)
    sliding = organ_boundary(mesh, "lung", mode="sliding")
    problem = ElasticProblem(mesh, LUNG, sliding)
    comp = compute_compliance(problem, CORRIDOR, TRACKED, LABELS)
    w_c, _ = interpolation(mesh, CORRIDOR)
    w_all, _ = interpolation(mesh, np.concatenate([CORRIDOR, TRACKED]))
    f = np.random.default_rng(4).normal(0, 0.05, (len(CORRIDOR), 3))
    d = np.array([0.3, 0.0, -3.0])
    u = problem.solve(w_c.T @ f.ravel(), problem.breathing_held(d))
    expected = w_all @ u.ravel()
    assert np.max(np.abs(comp.C @ f.ravel() + comp.B @ d - expected)) <= 1e-9 * np.abs(expected).max()
    n = sliding.sliding_normals
    us = u[sliding.held]
    normal = np.einsum("ij,ij->i", us, n)
    assert np.max(np.abs(normal - sliding.weight * (n @ d))) < 1e-12
    tangential = us - normal[:, None] * n
    assert np.max(np.linalg.norm(tangential, axis=1)) > 0.1  # the surface slid
    # the whole surface moved by d along its normals: a rigid translation, exactly
    rigid = ElasticProblem(mesh, LUNG, Boundary(sliding.held, np.ones(len(sliding.held)), "", n))
    assert np.max(np.abs(rigid.solve(None, rigid.breathing_held(d)) - d)) < 1e-12
    # softer than the held surface: the same loads move the target farther
    held = compute_compliance(ElasticProblem(mesh, LUNG, organ_boundary(mesh, "lung")),
                              CORRIDOR, TRACKED, LABELS)  # fmt: skip
    assert np.linalg.norm(comp.C[-9:-6] @ f.ravel()) > np.linalg.norm(held.C[-9:-6] @ f.ravel())
