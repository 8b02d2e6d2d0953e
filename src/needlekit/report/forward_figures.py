"""Forward-steering figures: the planar unicycle model and the 3D SE(3) model."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from needlekit.needle.bevel3d import propagate_bevel, simulate_bevel
from needlekit.needle.planar import simulate_planar
from needlekit.report._style import (
    _BLUE,
    _GREEN,
    _GREY,
    _INK,
    _MINUS,
    _PURPLE,
    _VERMILLION,
    _arrows_3d,
    _deg,
    _equal_3d,
    _frame_arrows,
    _heading_arrow,
    _new_figure,
    _style_3d,
)

#: Needle curvature of every forward example: a 50 mm radius, typical of a flexible
#: nitinol needle with a sharp bevel in soft tissue.
KAPPA_PER_MM = 1.0 / 50.0
#: Insertion speed of the forward examples (mm/s).
SPEED_MM_S = 5.0


@dataclass
class _PlanarCase:
    label: str
    colour: str
    inputs: np.ndarray  # (m, 3): speed_mm_s, bevel, duration_s
    states: np.ndarray  # (k, 3): z_mm, y_mm, theta_rad
    depth_mm: np.ndarray  # (k,) inserted length


@dataclass
class _PlanarData:
    cases: list[_PlanarCase]
    flip_state: np.ndarray
    closed_form_error_mm: float


def _planar_data() -> _PlanarData:
    v, half = SPEED_MM_S, 50.0 / SPEED_MM_S  # 50 mm per half, 100 mm in all
    specs = [
        ("λ = +1: bends toward +y", _VERMILLION, [[v, 1, 2 * half]]),
        (f"λ = {_MINUS}1: bends toward {_MINUS}y", _BLUE, [[v, -1, 2 * half]]),
        (f"λ = +1, flipped to {_MINUS}1 at 50 mm: S-curve", _GREEN, [[v, 1, half], [v, -1, half]]),
    ]
    cases = []
    for label, colour, inputs in specs:
        traj = simulate_planar(inputs, KAPPA_PER_MM, dt_s=0.05)
        cases.append(
            _PlanarCase(label, colour, np.array(inputs, float), traj.states, v * traj.time_s)
        )
    # closed form of the lambda = +1 arc: (r sin t, r (1 - cos t), t), t = kappa * length
    r, t = 1.0 / KAPPA_PER_MM, KAPPA_PER_MM * 100.0
    expected = np.array([r * np.sin(t), r * (1.0 - np.cos(t))])
    err = float(np.linalg.norm(cases[0].states[-1, :2] - expected))
    flip = cases[2].states[np.argmin(np.abs(cases[2].depth_mm - 50.0))]
    return _PlanarData(cases, flip, err)


def _plot_planar(d: _PlanarData) -> Figure:
    fig = _new_figure(11.5, 5.8)
    gs = fig.add_gridspec(1, 2, width_ratios=(1.0, 1.0))
    ax, ax2 = fig.add_subplot(gs[0]), fig.add_subplot(gs[1])
    r = 1.0 / KAPPA_PER_MM

    # the two circles of radius 1/kappa0 tangent to the start heading
    u = np.linspace(0.0, 2.0 * np.pi, 361)
    for sign in (1, -1):
        ax.plot(r * np.sin(u), sign * r * (1 - np.cos(u)), color="#bbbbbb", lw=0.9, ls=(0, (4, 3)))
    ax.plot(
        [], [], color="#bbbbbb", lw=0.9, ls=(0, (4, 3)), label=f"circles of radius 1/κ₀ = {r:g} mm"
    )

    for c in d.cases:
        z, y, th = c.states.T
        ax.plot(z, y, color=c.colour, label=c.label)
        _heading_arrow(ax, (z[-1], y[-1]), (np.cos(th[-1]), np.sin(th[-1])), 14.0, c.colour)
        ax.plot(z[-1], y[-1], "o", ms=5, color=c.colour, mec="white", mew=0.8, zorder=6)
        ax2.plot(c.depth_mm, np.degrees(th), color=c.colour)
        end_deg = float(np.degrees(th[-1]))
        ax2.annotate(
            _deg(end_deg, ".1f", sign=True),
            (c.depth_mm[-1], end_deg),
            xytext=(-4, 12 if end_deg >= -1e-9 else -12),
            textcoords="offset points",
            ha="right",
            va="center",
            fontsize=8.5,
            color=c.colour,
            weight="bold",
        )

    ax.plot(0, 0, "o", ms=8, color=_INK, zorder=6)
    _heading_arrow(ax, (0, 0), (1, 0), 16.0, _INK, lw=2.0)
    ax.annotate(
        "start, heading +z", (0, 0), xytext=(4, -16), textcoords="offset points", fontsize=8.5
    )
    fz, fy, _ = d.flip_state
    ax.plot(fz, fy, "D", ms=7, color=_GREEN, mec=_INK, mew=0.8, zorder=7)
    ax.annotate(
        "bevel flip (spin by π)\nafter 50 mm",
        (fz, fy),
        xytext=(16, 4),
        textcoords="offset points",
        fontsize=8.5,
        arrowprops={"arrowstyle": "-", "color": _GREY, "lw": 0.8},
    )
    ax.set_aspect("equal")
    ax.set_xlim(-56, 112)
    ax.set_ylim(-106, 106)
    ax.set_xlabel("z: insertion axis (mm)")
    ax.set_ylabel("y: lateral (mm)")
    ax.set_title("(a) Tip paths in the insertion plane, 100 mm inserted")
    fig.legend(loc="outside lower center", ncol=4, fontsize=8.5)

    ax2.axhline(0.0, color="#999999", lw=0.8)
    ax2.axvline(50.0, color=_GREEN, lw=0.8, ls=":")
    slope = math.degrees(KAPPA_PER_MM)
    ax2.text(
        4,
        100,
        f"θ̇ = λ κ₀ v   (slope ±{slope:.2f}°/mm)",
        fontsize=8.5,
        bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "#cccccc"},
    )
    ax2.set_xlabel("inserted length s = v t (mm)")
    ax2.set_ylabel("heading θ from +z toward +y (deg)")
    ax2.set_title("(b) Heading along the insertion")
    ax2.set_xlim(0, 100)
    ax2.set_ylim(-132, 132)
    fig.suptitle(
        f"Planar unicycle model, forward steering  (κ₀ = 1/{r:g} mm⁻¹, v = {SPEED_MM_S:g} mm/s)"
    )
    return fig


def _planar_json(d: _PlanarData) -> dict[str, Any]:
    return {
        "kappa_per_mm": KAPPA_PER_MM,
        "cases": [
            {
                "label": c.label,
                "inputs": [
                    {"speed_mm_s": float(a), "bevel": int(b), "duration_s": float(t)}
                    for a, b, t in c.inputs
                ],
                "inserted_length_mm": float(c.depth_mm[-1]),
                "final_z_mm": float(c.states[-1, 0]),
                "final_y_mm": float(c.states[-1, 1]),
                "final_theta_deg": float(np.degrees(c.states[-1, 2])),
            }
            for c in d.cases
        ],
        "closed_form_error_mm": d.closed_form_error_mm,
    }


# ---------------------------------------------------------------------------------------
# 2. 3D forward steering


@dataclass
class _BevelCase:
    label: str
    colour: str
    inputs: np.ndarray  # (m, 3): u1_mm_s, u2_rad_s, duration_s
    poses: np.ndarray  # (k, 4, 4)
    frame_idx: np.ndarray  # indices of the poses drawn as frames
    exact_end: np.ndarray  # (4, 4) from propagate_bevel


@dataclass
class _BevelData:
    cases: list[_BevelCase]
    helix: dict[str, float]
    planar_vs_3d_error_mm: float
    sampled_vs_exact_error_mm: float


def _bevel_data() -> _BevelData:
    v, half = SPEED_MM_S, 50.0 / SPEED_MM_S
    spin_rate = 0.25  # rad/s: 0.05 rad of spin per mm inserted
    helix = f"constant spin {spin_rate:g} rad/s while inserting: helix"
    specs = [
        ("pure insertion: circular arc", _VERMILLION, [[v, 0.0, 2 * half]]),
        (helix, _PURPLE, [[v, spin_rate, 3.5 * half]]),
        (
            "insert 50 mm, spin π in place, insert 50 mm: S-curve",
            _GREEN,
            [[v, 0, half], [0, np.pi, 1], [v, 0, half]],
        ),
        (
            "insert 50 mm, spin π/2 in place, insert 50 mm",
            _BLUE,
            [[v, 0, half], [0, np.pi / 2, 1], [v, 0, half]],
        ),
    ]
    g0 = np.eye(4)
    cases = []
    for label, colour, inputs in specs:
        inputs = np.array(inputs, dtype=float)
        traj = simulate_bevel(g0, inputs, KAPPA_PER_MM, dt_s=0.05)
        exact = propagate_bevel(g0, inputs, KAPPA_PER_MM)[-1]
        # inserted length at each sample, from the piecewise-constant insertion speed
        t_end = np.cumsum(inputs[:, 2])
        seg = np.minimum(np.searchsorted(t_end, traj.time_s - 1e-12), len(inputs) - 1)
        dt = np.diff(traj.time_s, prepend=0.0)
        depth = np.cumsum(inputs[seg, 0] * dt)
        marks = np.arange(0.0, depth[-1] + 1e-9, 40.0)
        idx = np.array([np.flatnonzero(depth >= m - 1e-9)[-1 if m == 0 else 0] for m in marks])
        idx[0] = 0
        cases.append(_BevelCase(label, colour, inputs, traj.world_T_tip, idx, exact))

    sampled_err = max(
        float(np.linalg.norm(c.poses[-1] - c.exact_end)) for c in cases
    )  # same exponential, sampled vs in one step

    # helix: the screw of the twist (0, 0, 1, kappa, 0, tau) per mm
    tau = spin_rate / v
    w2 = KAPPA_PER_MM**2 + tau**2
    radius, pitch = KAPPA_PER_MM / w2, 2 * np.pi * tau / w2
    turn_len = 2 * np.pi / np.sqrt(w2)  # inserted length of one full turn
    after_turn = propagate_bevel(g0, [[v, spin_rate, turn_len / v]], KAPPA_PER_MM)[-1]
    pitch_err = abs(float(np.linalg.norm(after_turn[:3, 3])) - pitch)
    # screw axis: direction omega / |omega|, through omega x v / |omega|^2 (body = world here)
    omega, lin = np.array([KAPPA_PER_MM, 0.0, tau]), np.array([0.0, 0.0, 1.0])
    helix = {
        "axis_direction": (omega / np.sqrt(w2)).tolist(),
        "axis_point_mm": (np.cross(omega, lin) / w2).tolist(),
        "spin_per_mm_rad": tau,
        "radius_mm": radius,
        "pitch_mm": pitch,
        "turn_length_mm": turn_len,
        "pitch_check_error_mm": pitch_err,
    }

    # the planar model with lambda = -1 is the 3D model in the tip's y-z plane, no spin
    planar = simulate_planar([[v, -1, half], [v, 1, half]], KAPPA_PER_MM).final_state
    p3 = cases[2].exact_end[:3, 3]
    planar_err = float(np.linalg.norm([p3[0], p3[1] - planar[1], p3[2] - planar[0]]))
    return _BevelData(cases, helix, planar_err, sampled_err)


def _plot_bevel(d: _BevelData) -> Figure:
    fig = _new_figure(11.5, 7.0)
    gs = fig.add_gridspec(1, 2, width_ratios=(1.15, 1.0))
    ax = fig.add_subplot(gs[0], projection="3d")
    ax2 = fig.add_subplot(gs[1])
    _style_3d(ax)
    allp = []
    for c in d.cases:
        p = c.poses[:, :3, 3]
        allp.append(p)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], color=c.colour, lw=2.4, label=c.label)
        fr = c.poses[c.frame_idx[1:]]
        _arrows_3d(ax, fr[:, :3, 3], fr[:, :3, 2], 13.0, _INK)
        _arrows_3d(ax, fr[:, :3, 3], -fr[:, :3, 1], 9.0, _GREY)
        ax.scatter(*p[-1], color=c.colour, s=22, depthshade=False)
        ax2.plot(p[:, 0], p[:, 1], color=c.colour, lw=2.2)
        ax2.plot(p[-1, 0], p[-1, 1], "o", ms=5, color=c.colour, mec="white", mew=0.8)
    h = d.helix
    axis_pts = np.asarray(h["axis_point_mm"]) + np.outer([-20.0, 150.0], h["axis_direction"])
    ax.plot(*axis_pts.T, color=_PURPLE, lw=1.0, ls=(0, (5, 4)), label="screw axis of the helix")
    ax2.plot(*axis_pts[:, :2].T, color=_PURPLE, lw=1.0, ls=(0, (5, 4)))
    _frame_arrows(ax, np.eye(4)[None], 16.0)
    ax.scatter([0], [0], [0], color=_INK, s=30, depthshade=False)
    ax.text(3, 3, -9, "start", fontsize=8.5)
    allp = np.concatenate(allp)
    _equal_3d(ax, np.vstack([allp, [[0, 0, -10], [20, 0, 0]]]), 4.0)
    ax.view_init(elev=16, azim=-30)
    ax.set_xlabel("x (mm)", labelpad=2)
    ax.set_ylabel("y (mm)", labelpad=2)
    ax.set_zlabel("z (mm)", labelpad=2)
    ax.set_title("(a) Tip paths from the identity pose (insertion along +z)", loc="left")
    handles, labels = ax.get_legend_handles_labels()
    handles += [
        Line2D([], [], color=_INK, lw=0, marker=r"$\uparrow$", ms=11),
        Line2D([], [], color=_GREY, lw=0, marker=r"$\uparrow$", ms=11),
        Line2D([], [], color=_INK, lw=0, marker="$xyz$", ms=16),
    ]
    labels += [
        "tip z axis (insertion), every 40 mm inserted",
        f"bending side (tip {_MINUS}y axis), every 40 mm inserted",
        "start frame: x red, y green, z blue",
    ]
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=8.5)

    ax2.axhline(0, color="#999999", lw=0.7)
    ax2.axvline(0, color="#999999", lw=0.7)
    ax2.plot(0, 0, "o", ms=7, color=_INK, zorder=6)
    ax2.set_aspect("equal")
    ax2.set_xlabel("x (mm)")
    ax2.set_ylabel("y (mm)")
    ax2.set_title("(b) End-on view, looking down the start axis")
    ax2.text(
        0.97,
        0.04,
        "Spinning turns the bending side with the bevel:\n"
        "by π it reverses the bend (S-curve), by π/2 it\n"
        "leaves the first plane. Spinning while inserting\n"
        f"gives a helix: radius {h['radius_mm']:.1f} mm, pitch {h['pitch_mm']:.1f} mm,\n"
        f"one turn per {h['turn_length_mm']:.0f} mm inserted.",
        transform=ax2.transAxes,
        fontsize=8.5,
        va="bottom",
        ha="right",
        bbox={"boxstyle": "round,pad=0.4", "fc": "white", "ec": "#cccccc"},
    )
    ax2.set_xlim(-12, 66)
    ax2.set_ylim(-108, 12)
    fig.suptitle(
        "3D bevel-tip model in SE(3), forward steering  "
        f"(κ = 1/{1 / KAPPA_PER_MM:g} mm⁻¹, u₁ = {SPEED_MM_S:g} mm/s)"
    )
    return fig


def _bevel_json(d: _BevelData) -> dict[str, Any]:
    return {
        "kappa_per_mm": KAPPA_PER_MM,
        "cases": [
            {
                "label": c.label,
                "inputs": [
                    {"u1_mm_s": float(a), "u2_rad_s": float(b), "duration_s": float(t)}
                    for a, b, t in c.inputs
                ],
                "final_pose": c.exact_end.tolist(),
            }
            for c in d.cases
        ],
        "helix": d.helix,
        "planar_vs_3d_s_curve_error_mm": d.planar_vs_3d_error_mm,
        "sampled_vs_exact_end_error": d.sampled_vs_exact_error_mm,
    }


# ---------------------------------------------------------------------------------------
# 3. inverse steering
