"""Inverse-steering figure: transformation-matrix arcs to targets and planar way-points."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from needlekit.geometry.arcs import propagate_arcs
from needlekit.geometry.se3 import make_pose, transform_points
from needlekit.geometry.so3 import rot_x, rot_z
from needlekit.needle.planar import planar_steer_waypoints, simulate_planar
from needlekit.needle.reachability import (
    is_reachable,
)
from needlekit.needle.transform_method import tm_inverse, tm_waypoints
from needlekit.report._style import (
    _ALPHA,
    _AXIS_COLOURS,
    _BLUE,
    _GREY,
    _INK,
    _MINUS,
    _PALETTE,
    _VERMILLION,
    _arrows_3d,
    _deg,
    _equal_3d,
    _f,
    _frame_arrows,
    _heading_arrow,
    _new_figure,
    _style_3d,
)

#: Minimum radius for the 3D inverse-steering targets (mm), as in the CLI example.
R_MIN_INVERSE_MM = 30.0
#: Seed of the random targets.
SEED = 0


@dataclass
class _InverseData:
    world_T_tip: np.ndarray
    targets: np.ndarray  # (n, 3) world
    alpha: np.ndarray
    radius: np.ndarray
    phi: np.ndarray
    length: np.ndarray
    dense: np.ndarray  # (n, k, 3)
    dots: np.ndarray  # (n, m, 3)
    end_poses: np.ndarray  # (n, 4, 4)
    end_error_mm: float
    twist_position_error_mm: float
    twist_rotation_error: float
    n_steps: int
    # planar way-point steering
    waypoints: np.ndarray  # (m, 2) z, y
    steps: list = field(default_factory=list)
    states: np.ndarray | None = None  # (m + 1, 3)
    arcs: list = field(default_factory=list)  # per step (k, 3) states
    planar_error_mm: float = 0.0
    lecture_arc: np.ndarray | None = None  # the slide's radius for the first way-point
    lecture_radius_mm: float = 0.0
    lecture_miss_mm: float = 0.0


def _random_targets(rng: np.random.Generator, n: int) -> np.ndarray:
    """Targets in the tip frame a single arc with radius >= R_MIN_INVERSE_MM reaches."""
    out = []
    while len(out) < n:
        axial = rng.uniform(45.0, 110.0)
        radial = rng.uniform(12.0, 45.0)
        # spread the bending planes around the axis: one sector of 2 pi / n per target
        az = 2.0 * np.pi * (len(out) + rng.uniform(0.15, 0.85)) / n - np.pi
        p = np.array([radial * np.cos(az), radial * np.sin(az), axial])
        if is_reachable(np.eye(4), p, R_MIN_INVERSE_MM):
            out.append(p)
    return np.array(out)


def _inverse_data() -> _InverseData:
    rng = np.random.default_rng(SEED)
    world_T_tip = make_pose(rot_z(0.6) @ rot_x(-0.45), [10.0, -20.0, 5.0])
    targets = transform_points(world_T_tip, _random_targets(rng, 5))
    sol = tm_inverse(targets, world_T_tip, r_min_mm=R_MIN_INVERSE_MM)
    n_steps = 10
    dense = tm_waypoints(sol, 90)[..., :3, 3]
    dots = tm_waypoints(sol, n_steps)[..., :3, 3]
    ends = sol.end_poses()
    end_err = float(np.max(np.linalg.norm(ends[:, :3, 3] - targets, axis=1)))
    # the same arcs in the twist model: spin psi = alpha + pi/2, R_tm = R_twist Rz(-pi/2)
    twist_ends = propagate_arcs(
        world_T_tip, sol.alpha_rad + np.pi / 2, sol.kappa_per_mm, sol.length_mm
    )
    twist_pos_err = float(np.max(np.linalg.norm(twist_ends[:, :3, 3] - ends[:, :3, 3], axis=1)))
    twist_rot_err = float(
        np.max(np.abs(twist_ends[:, :3, :3] @ rot_z(-np.pi / 2) - ends[:, :3, :3]))
    )

    waypoints = np.array([[30.0, 10.0], [60.0, 22.0], [95.0, 15.0], [125.0, -5.0]])
    steps, states = planar_steer_waypoints(waypoints)
    arcs, errs = [], []
    for step, s0, wp in zip(steps, states[:-1], waypoints, strict=True):
        traj = simulate_planar(step.inputs(1.0), step.kappa_per_mm, state0=s0, dt_s=0.01)
        arcs.append(traj.states)
        errs.append(float(np.linalg.norm(traj.final_state[:2] - wp)))

    # the slide's radius (y^2 + z^2) / |y| for the first way-point, with its own length
    z1, y1 = waypoints[0]
    r_lect = (y1 * y1 + z1 * z1) / abs(y1)
    l_lect = r_lect * math.atan2(z1, r_lect - abs(y1))
    lect = simulate_planar([[l_lect, 1, 1.0]], 1.0 / r_lect, dt_s=0.01).states
    miss = float(np.linalg.norm(lect[-1, :2] - waypoints[0]))
    return _InverseData(
        world_T_tip,
        targets,
        sol.alpha_rad,
        sol.radius_mm,
        sol.phi_rad,
        sol.length_mm,
        dense,
        dots,
        ends,
        end_err,
        twist_pos_err,
        twist_rot_err,
        n_steps,
        waypoints,
        steps,
        states,
        arcs,
        max(errs),
        lect,
        r_lect,
        miss,
    )


def _inverse_3d(ax, leg_ax, d: _InverseData) -> None:
    """Panel (a): the arcs to the targets in 3D from the tip frame, and the legend."""
    g = d.world_T_tip
    tip, axis = g[:3, 3], g[:3, 2]
    shaft = tip + np.outer([-30.0, 0.0], axis)
    ahead = tip + np.outer([0.0, 125.0], axis)
    ax.plot(*shaft.T, color="#9a9a9a", lw=5.0, solid_capstyle="butt", label="needle shaft")
    ax.plot(*ahead.T, color=_GREY, lw=1.0, ls=(0, (5, 4)), label="needle axis (straight ahead)")
    _frame_arrows(ax, g[None], 20.0)
    ax.scatter(*tip, color=_INK, s=36, depthshade=False)
    for i in range(d.targets.shape[0]):
        colour = _PALETTE[i % len(_PALETTE)]
        label = (
            f"T{i + 1}: r = {d.radius[i]:.1f} mm, φ = {_deg(np.degrees(d.phi[i]), '.1f')}, "
            f"{_ALPHA} = {_deg(np.degrees(d.alpha[i]), '.0f')}, l = {d.length[i]:.1f} mm"
        )
        ax.plot(*d.dense[i].T, color=colour, lw=2.2, label=label)
        ax.scatter(*d.dots[i, 1:-1].T, color=colour, s=12, depthshade=False)
        ax.scatter(
            *d.targets[i],
            color=colour,
            s=80,
            marker="X",
            edgecolor=_INK,
            linewidth=0.6,
            depthshade=False,
        )
        ax.text(
            *(d.targets[i] + [0.0, 0.0, 6.0]),
            f"T{i + 1}",
            fontsize=9.5,
            weight="bold",
            color=colour,
        )
    _arrows_3d(ax, d.end_poses[:, :3, 3], d.end_poses[:, :3, 2], 10.0, _INK)
    pts = np.vstack([d.dense.reshape(-1, 3), ahead, shaft])
    _equal_3d(ax, pts, 5.0)
    ax.view_init(elev=14, azim=-75)
    ax.set_xlabel("x (mm)", labelpad=2)
    ax.set_ylabel("y (mm)", labelpad=2)
    ax.set_zlabel("z (mm)", labelpad=2)
    ax.set_title(
        f"(a) Transformation-matrix method: one arc per target (r ≥ {R_MIN_INVERSE_MM:g} mm)",
        loc="left",
    )
    handles, labels = ax.get_legend_handles_labels()
    handles += [
        Line2D([], [], color=_INK, lw=0, marker="o", ms=3.5),
        Line2D([], [], color=_INK, lw=0, marker=r"$\uparrow$", ms=11),
        Line2D([], [], color=_INK, lw=0, marker="$xyz$", ms=16),
    ]
    labels += [
        f"way-points: φ split in {d.n_steps} equal steps (tm_waypoints)",
        "tip z axis on arrival (tangent of the arc)",
        f"tip frame: x red, y green, z blue ({_ALPHA} is measured from x)",
    ]
    leg_ax.legend(handles, labels, loc="center", ncol=2, fontsize=8, borderaxespad=0.0)


def _inverse_planar(ax2, d: _InverseData) -> None:
    """Panel (b): planar steering way-point by way-point, beside the slide's radius."""
    # (b) planar way-point-wise steering
    colours = {1: _VERMILLION, -1: _BLUE}
    for step, arc in zip(d.steps, d.arcs, strict=True):
        ax2.plot(arc[:, 0], arc[:, 1], color=colours[step.bevel], lw=2.4)
        mid = arc[len(arc) // 2]
        normal = np.array([-np.sin(mid[2]), np.cos(mid[2])]) * step.bevel
        off = -normal * 7.0  # outside the bend
        ax2.annotate(
            f"r = {step.radius_mm:.1f} mm\nl = {step.length_mm:.1f} mm",
            (mid[0], mid[1]),
            xytext=(mid[0] + off[0], mid[1] + off[1]),
            fontsize=8,
            ha="center",
            va="center",
            color=colours[step.bevel],
        )
    lect = d.lecture_arc
    ax2.plot(lect[:, 0], lect[:, 1], color=_GREY, lw=1.4, ls=(0, (2, 2)))
    ax2.plot(lect[-1, 0], lect[-1, 1], "x", color=_GREY, ms=7, mew=1.6)
    ax2.annotate(
        f"slide's r = (y² + z²)/|y| = {d.lecture_radius_mm:.0f} mm\n"
        f"misses W1 by {d.lecture_miss_mm:.1f} mm",
        (lect[-1, 0], lect[-1, 1]),
        xytext=(62, -34),
        textcoords="offset points",
        fontsize=8,
        color="#555555",
        ha="center",
        arrowprops={"arrowstyle": "-", "color": _GREY, "lw": 0.8},
    )
    label_offsets = ((-9, 9), (-3, 11), (-6, 10), (-9, 9))  # clear of the arc labels
    for i, (s, wp) in enumerate(zip(d.states[1:], d.waypoints, strict=True)):
        ax2.plot(*wp, "o", ms=8, mfc="white", mec=_INK, mew=1.5, zorder=6)
        _heading_arrow(ax2, wp, (np.cos(s[2]), np.sin(s[2])), 9.0, _INK, lw=1.2)
        ax2.annotate(
            f"W{i + 1}",
            wp,
            xytext=label_offsets[i % 4],
            textcoords="offset points",
            ha="center",
            weight="bold",
        )
    ax2.plot(0, 0, "o", ms=8, color=_INK, zorder=6)
    _heading_arrow(ax2, (0, 0), (1, 0), 12.0, _INK, lw=1.8)
    ax2.set_aspect("equal")
    ax2.set_xlim(-8, 140)
    ax2.set_ylim(-22, 48)
    ax2.set_xlabel("z: insertion axis (mm)")
    ax2.set_ylabel("y: lateral (mm)")
    ax2.set_title("(b) Planar steering way-point by way-point (one arc each)")
    ax2.legend(
        [
            Line2D([], [], color=_VERMILLION, lw=2.4),
            Line2D([], [], color=_BLUE, lw=2.4),
            Line2D([], [], color=_INK, lw=0, marker="o", mfc="white", ms=7),
            Line2D([], [], color=_GREY, lw=1.4, ls=(0, (2, 2))),
        ],
        [
            "arc with bevel λ = +1",
            f"arc with bevel λ = {_MINUS}1",
            "way-point, heading on arrival",
            "lecture slide's radius (factor 2 missing)",
        ],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.2),
        ncol=2,
        fontsize=8,
    )


def _inverse_down_axis(ax3, d: _InverseData) -> None:
    """Panel (c): the targets down the needle axis, in the tip frame (the angle alpha)."""
    g = d.world_T_tip
    tip = g[:3, 3]
    # (c) the same targets seen down the needle axis, in the tip frame
    local = (d.targets - tip) @ g[:3, :3]
    lim = 1.18 * float(np.max(np.abs(local[:, :2])))
    ax3.axhline(0, color="#bbbbbb", lw=0.7)
    ax3.axvline(0, color="#bbbbbb", lw=0.7)
    _heading_arrow(ax3, (0, 0), (1, 0), 0.3 * lim, _AXIS_COLOURS[0], lw=1.8)
    _heading_arrow(ax3, (0, 0), (0, 1), 0.3 * lim, _AXIS_COLOURS[1], lw=1.8)
    ax3.text(0.31 * lim, -0.07 * lim, "tip x", color=_AXIS_COLOURS[0], fontsize=8.5)
    ax3.text(0.03 * lim, 0.31 * lim, "tip y", color=_AXIS_COLOURS[1], fontsize=8.5)
    for i, q in enumerate(local):
        colour = _PALETTE[i % len(_PALETTE)]
        arc_local = (d.dense[i] - tip) @ g[:3, :3]
        ax3.plot(arc_local[:, 0], arc_local[:, 1], color=colour, lw=2.2)
        ax3.plot(q[0], q[1], "X", ms=9, color=colour, mec=_INK, mew=0.6)
        rr = 0.16 * lim + 0.05 * lim * i
        a = np.linspace(0.0, d.alpha[i], 60)
        ax3.plot(rr * np.cos(a), rr * np.sin(a), color=colour, lw=0.9)
        ax3.annotate(
            f"T{i + 1}  {_ALPHA} = {_deg(np.degrees(d.alpha[i]), '.0f')}, "
            f"k = {np.hypot(*q[:2]):.1f} mm",
            (q[0], q[1]),
            xytext=(0, 9 if q[1] >= 0 else -14),
            textcoords="offset points",
            ha="center",
            fontsize=8,
            color=colour,
            weight="bold",
        )
    ax3.plot(0, 0, "o", ms=7, color=_INK, zorder=6)
    ax3.set_aspect("equal")
    ax3.set_xlim(-lim, lim)
    ax3.set_ylim(-lim, lim)
    ax3.set_xlabel("tip x (mm)")
    ax3.set_ylabel("tip y (mm)")
    ax3.set_title(f"(c) Down the needle axis: bending-plane angle {_ALPHA}")


def _plot_inverse(d: _InverseData) -> Figure:
    fig = _new_figure(14.0, 8.6)
    gs = fig.add_gridspec(3, 2, width_ratios=(1.1, 1.0), height_ratios=(1.0, 1.0, 0.3))
    ax = fig.add_subplot(gs[0:2, 0], projection="3d")
    ax2 = fig.add_subplot(gs[0, 1])
    ax3 = fig.add_subplot(gs[1:, 1])
    leg_ax = fig.add_subplot(gs[2, 0])
    leg_ax.axis("off")
    _style_3d(ax)
    _inverse_3d(ax, leg_ax, d)
    _inverse_planar(ax2, d)
    _inverse_down_axis(ax3, d)
    fig.suptitle("Inverse steering: from a tip pose and a target to the arc that reaches it")
    return fig


def _inverse_json(d: _InverseData) -> dict[str, Any]:
    return {
        "r_min_mm": R_MIN_INVERSE_MM,
        "seed": SEED,
        "world_T_tip": d.world_T_tip.tolist(),
        "targets": [
            {
                "target_mm": d.targets[i].tolist(),
                "alpha_rad": float(d.alpha[i]),
                "alpha_deg": float(np.degrees(d.alpha[i])),
                "radius_mm": _f(d.radius[i]),
                "phi_rad": float(d.phi[i]),
                "phi_deg": float(np.degrees(d.phi[i])),
                "length_mm": float(d.length[i]),
            }
            for i in range(d.targets.shape[0])
        ],
        "n_steps": d.n_steps,
        "end_point_error_mm": d.end_error_mm,
        "twist_model_position_error_mm": d.twist_position_error_mm,
        "twist_model_rotation_error": d.twist_rotation_error,
        "planar_waypoints": {
            "sampling_time_s": 1.0,
            "waypoints_zy_mm": d.waypoints.tolist(),
            "steps": [
                {
                    "radius_mm": _f(s.radius_mm),
                    "length_mm": float(s.length_mm),
                    "bevel": int(s.bevel),
                    "angle_deg": float(np.degrees(s.angle_rad)),
                    "speed_mm_s": float(s.speed_mm_s),
                }
                for s in d.steps
            ],
            "forward_check_error_mm": d.planar_error_mm,
            "lecture_slide_radius_w1_mm": d.lecture_radius_mm,
            "lecture_slide_miss_w1_mm": d.lecture_miss_mm,
        },
    }


# ---------------------------------------------------------------------------------------
# 4. reachability
