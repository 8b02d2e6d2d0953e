"""The effective puncture region and the start-direction sweep (Feng et al. 2023)."""

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.sweep import (
    effective_directions,
    pose_from_direction,
    sphere_directions,
    sweep,
)


def test_sphere_directions_are_unit_and_spread():
    d = sphere_directions(544)
    assert d.shape == (544, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.linalg.norm(d.mean(axis=0)) < 0.01  # no preferred side
    # nearest-neighbour angles are all close to the ideal spacing for 544 points
    cos = d @ d.T
    np.fill_diagonal(cos, -1.0)
    nn = np.degrees(np.arccos(cos.max(axis=1)))
    assert nn.min() > 0.6 * nn.mean() and nn.max() < 1.4 * nn.mean()
    with pytest.raises(InvalidInputError, match="n"):
        sphere_directions(0)


@pytest.mark.parametrize("alpha", [0.0, 20.0, 45.0, 70.0])
def test_effective_region_is_the_spherical_cap_theta_below_90_minus_alpha(alpha):
    d = sphere_directions(20000)
    n = np.array([0.3, -0.4, 0.866])
    eff = effective_directions(d, n, alpha)
    # cap of polar angle 90 - alpha: area fraction (1 - cos(90 - alpha)) / 2 = (1 - sin alpha) / 2
    assert eff.mean() == pytest.approx((1 - np.sin(np.radians(alpha))) / 2, abs=0.002)
    theta = np.degrees(np.arccos(np.clip(d @ (n / np.linalg.norm(n)), -1, 1)))
    assert np.all(theta[eff] <= 90 - alpha + 1e-9)


def test_pose_from_direction():
    g = pose_from_direction([1.0, 2.0, 3.0], [0.0, 3.0, 4.0])
    assert np.allclose(g[:3, 2], [0, 0.6, 0.8]) and np.allclose(g[:3, 3], [1, 2, 3])
    assert np.allclose(g[:3, :3].T @ g[:3, :3], np.eye(3)) and np.linalg.det(
        g[:3, :3]
    ) == pytest.approx(1.0)


@pytest.mark.slow
def test_lung_phantom_sweep_mean_costs_as_measured(exact_clearance):
    from needlekit.anatomy.phantoms import lung_phantom

    ph = lung_phantom(0)
    prob = SteerableProblem(
        ph.scene, goal_mm=ph.targets_mm[0], start_pose=ph.start_poses[0], r_min_mm=50.0,
        max_length_mm=100.0, min_puncture_angle_deg=20.0, entry_surface="airways",
    )  # fmt: skip
    # iteration budgets, not time, so the anytime planners' results do not depend on load;
    # RCS and RRT join the goal with one arc, as in the implementation behind Feng's tables
    kw = {"time_limit_s": 60.0, "max_iterations": 200}
    runs = {p: sweep(prob, p, **kw) for p in ("rcs_star", "rcs")}
    runs["rrt"] = sweep(prob, "rrt", options={"connection": "arc"}, **kw)
    for s in runs.values():
        assert s.stats["n_effective"] == pytest.approx(
            544 * (1 - np.sin(np.radians(20))) / 2, abs=3
        )
        assert (s.stats["n_effective"], s.stats["n_solved"]) == (178, 18)
    mean = {p: s.stats["mean_cost_mm"] for p, s in runs.items()}
    # what needlekit measures here (iteration budgets: the same on any machine): RCS* is
    # lowest, as in Feng's Table 4, but RCS < RRT, where Feng has RRT < RCS; on this
    # phantom every solved direction is the direct turn-then-straight path, so the three
    # differ by under 1 mm (docs/steerable.md)
    assert mean == pytest.approx({"rcs_star": 32.474056, "rcs": 33.366337, "rrt": 33.381740})
    # RRT's default greedy connection, arc then line, is never worse than one arc here
    arc_line = sweep(prob, "rrt", **kw)
    assert arc_line.stats["n_solved"] == runs["rrt"].stats["n_solved"]
    assert arc_line.stats["mean_cost_mm"] <= mean["rrt"] + 1e-9
    # the exact oracle: every plan returned (solved, or the nearest valid path) clears the
    # phantom's exact anatomy, by at least the clearance the planner certified
    checked = 0
    for s in [*runs.values(), arc_line]:
        for r in s.results:
            if r is not None and r.plan is not None:
                exact_clearance(ph, prob, r.plan, r.stats["certified_clearance_mm"])
                checked += 1
    assert checked == 4 * 18
    best = runs["rcs_star"].best
    assert best.plan is not None and best.stats["certified"]
    table = runs["rcs_star"].to_dict()
    assert (
        len(table["directions"]) == 544
        and table["summary"]["best_index"] == runs["rcs_star"].stats["best_index"]
    )


@pytest.mark.parametrize("nside", [1, 2, 7, 16])
def test_healpix_directions_are_equal_area(nside):
    from needlekit.planning.steerable.sweep import healpix_directions

    d = healpix_directions(nside)
    assert d.shape == (12 * nside**2, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.allclose(d.mean(axis=0), 0.0, atol=1e-12)  # symmetric sets
    if nside >= 7:  # equal areas: the share in a cap is its area fraction
        for alpha in (0.0, 20.0, 45.0):
            eff = effective_directions(d, [0.0, 0.0, 1.0], alpha)
            assert eff.mean() == pytest.approx(
                (1 - np.sin(np.radians(alpha))) / 2, abs=3.0 / nside**2
            )
    with pytest.raises(InvalidInputError, match="nside"):
        healpix_directions(0)


def test_the_progress_learns_the_total_before_the_first_direction():
    from pathlib import Path

    from needlekit.cli._common import sweep_progress
    from needlekit.scenario.problems import load_problem

    _, problem = load_problem(Path(__file__).parents[2] / "examples" / "toy.yaml")
    calls = []

    class Progress:
        def set_total(self, n):
            calls.append(("total", n))

        def __call__(self, result):
            calls.append(("done", result is not None))

    dirs = sphere_directions(24)
    s = sweep(problem, "rcs_star", directions=dirs, max_iterations=20, progress=Progress())
    n = int(s.effective.sum())
    assert 0 < n < len(dirs)
    assert calls == [("total", n)] + [("done", True)] * n
    # the command's bars take the total too (tqdm then shows the share done and time left)
    with sweep_progress() as progress:
        update = progress("rcs_star")
        update.set_total(n)
        assert update.bar.total == n
