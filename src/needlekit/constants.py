"""Tolerances and defaults, each in one place with the reason for its value.

Algorithms import these instead of writing literals, so a tolerance can be found, argued
about and changed once (the role of OMPL's ``MagicConstants.h`` or trimesh's
``constants.py``).
"""

from __future__ import annotations

#: Angles below this (rad) are treated as zero in closed forms such as the SE(3)
#: exponential, where a Taylor series takes over. At 1e-6 rad the neglected series terms
#: are below 1e-24 relative, far under double precision.
SMALL_ANGLE_RAD: float = 1e-6

#: Tolerance on a rotation matrix: ``|R^T R - I|`` and ``|det R - 1|`` must stay below it.
#: Loose enough for matrices read from text files with ~9 significant digits.
ROTATION_ORTHONORMAL_TOL: float = 1e-6

#: Relative determinant of the Euler-rate map T(phi) below which the angles are treated
#: as gimbal-locked: there ``|det T| = |cos|`` or ``|sin|`` of the middle angle, so 1e-9
#: means within ~1e-9 rad of the singularity, where the inverse would amplify rates 1e9x.
GIMBAL_LOCK_TOL: float = 1e-9

#: Lateral offset (mm) below which a target counts as lying on the needle axis, so the
#: steering arc degenerates to a straight line (radius treated as infinite). 1e-12 mm is
#: far below any physical meaning and keeps the closed forms accurate to ~1e-9 mm for
#: targets up to a metre away.
ON_AXIS_TOL_MM: float = 1e-12

#: Default spacing (mm) of points sampled densely along an arc for clearance checks and
#: exported paths; plan files promise at most 0.5 mm.
DEFAULT_SAMPLE_SPACING_MM: float = 0.5

#: Most samples a sampled tip trajectory may hold (``kinematics forward --dt-s``). Each
#: sample is a 4x4 float64 pose (128 bytes) with temporaries of the same size, so 10^6
#: samples take a few hundred MB and print ~100 MB of table: beyond any reader, and the
#: segment ends are exact at any sampling interval anyway.
MAX_TRAJECTORY_SAMPLES: int = 1_000_000

#: A scenario whose anatomy is smaller than this across (mm) gets a warning that lengths
#: are millimetres: the smallest anatomy planned here (a 2-3 cm nodule and its
#: surroundings) is far larger, so such a scene was almost surely written in cm or m.
MM_WARNING_MIN_EXTENT_MM: float = 5.0

#: A needle whose minimum radius of curvature is below this (mm) gets the same warning:
#: bevel-tip needles in tissue bend with radii of tens of mm (Feng et al. use 50 mm).
MM_WARNING_MIN_R_MIN_MM: float = 1.0

#: Part of a planner's time budget (s, at most; and at most 5 % of it) kept back from the
#: search for building and checking the path it returns, so that a run answers within its
#: budget. One search step plus the final check take about 1-2 ms on a Med-RAD lung.
PLANNER_FINISH_RESERVE_S: float = 0.01

# -- the default needle and budget (written once; scenario files, problems, the command line
# and the benchmarks read these) ----------------------------------------------------------

#: Needle diameter (mm): the Med-RAD benchmark's needle, as in the reference planner's set-up.
DEFAULT_NEEDLE_DIAMETER_MM: float = 1.0
#: Minimum radius of curvature (mm) of a bevel-tip needle in soft tissue (Feng et al. use 50).
DEFAULT_R_MIN_MM: float = 50.0
#: Longest insertion (mm), l_max of the Med-RAD benchmark.
DEFAULT_MAX_LENGTH_MM: float = 150.0
#: Largest change of direction along a path (deg); the reference planner refuses more.
DEFAULT_MAX_HEADING_CHANGE_DEG: float = 90.0
#: Obstacles this close to the start (mm) are ignored: a transbronchial needle leaves the
#: airway through its wall (the reference planner's whitelist radius).
DEFAULT_START_EXCLUSION_MM: float = 3.0

# -- the clearance rule (one for every steerable planner's search and for the plan check) --
#
# A sampled motion is clear when, at every sample outside the start exclusion,
#
#     model distance - needle radius - model error bound - half the sample gap >= margin,
#
# where the collision model's distance is 1-Lipschitz (the obstacle field; for
# ``voxel_centres`` the distance to the obstacle voxel balls, exact in that model), so that
# every point between two samples is clear too. The search applies it to each motion with
# MOTION_SPACING_MM (the gap is the spacing, whatever the motion's length) plus
# CLEARANCE_ROUNDING_MM; the plan check re-derives the same samples from the plan's
# primitives and certifies them with the same rule, so every plan a search accepts passes
# the check and both report the same clearance. The check's denser samples
# (VERIFY_SPACING_MM) are a second certificate: the plan is clear when either proves it.

#: Spacing of the collision samples along the planners' motions (mm), as in the reference
#: steerable-needle planner (its 0.5 mm sample points).
MOTION_SPACING_MM: float = 0.5
#: Spacing of the plan check's dense samples (mm): half the motion spacing, so that its
#: certificate loses only 0.125 mm to the gaps and the check sees between the search's
#: samples.
VERIFY_SPACING_MM: float = 0.25
#: How far above the rule's threshold (mm) the search wants a sample: the plan check
#: re-derives the search's samples from the primitives with other kernels, which move a
#: point by ~1e-12 mm on a 150 mm path, so a sample the search accepts passes the check.
CLEARANCE_ROUNDING_MM: float = 1e-9
#: Goal tolerance tau (mm), Feng et al.'s and the reference planner's.
DEFAULT_GOAL_TOLERANCE_MM: float = 1.0
#: Planning budget per run (s): Feng et al.'s 1 s per start direction.
DEFAULT_TIME_LIMIT_S: float = 1.0

#: Shortest distance gradient (its length) accepted as a surface normal. A true signed
#: distance has a unit gradient wherever the surface normal is defined; on the medial axis
#: (e.g. a sphere's centre) central differences give a much shorter one, and interpolated
#: grids stay above ~0.7 away from it. Below this the normal counts as undefined.
MIN_NORMAL_GRADIENT: float = 0.5

# -- the clearance rule of the straight (multi-needle) planners and of verify_multi ---------
#
# A straight needle (the segment target-entry, its tube of the needle's radius) is clear
# when
#
#     certified distance of the axis to the obstacles - needle radius >= gamma,
#
# where the certified distance is, over consecutive samples t_i < t_j of the axis, the
# smallest ``(d_i + d_j - (t_j - t_i)) / 2`` (a signed distance is 1-Lipschitz, so no
# point between two samples is nearer), capped at radius + gamma + STRAIGHT_CAP_ABOVE_GAMMA_MM,
# less the field's stated error bound; a placed needle's tube counts in closed form, its
# head by the tangent bound of a convex solid. The planner samples by sphere tracing with
# STRAIGHT_NEAR_STEP_MM near obstacles (so its bound is at most half of it below the
# sampled minimum); the check adds a dense certificate (STRAIGHT_CHECK_STEP_MM). A plan is
# written rounded to RECORD_DECIMALS, so the planner certifies the segment exactly as the
# record holds it (both certificates, the better counts) before it accepts a direction,
# and its map keeps RECORD_ROUNDING_ALLOWANCE_MM above gamma so that rounding the chosen
# direction's points seldom costs it; verify_multi re-derives the same numbers from the
# record, so every needle a plan holds passes the check, with the same clearance.

#: Largest sphere-tracing step (mm) of the straight planners near obstacles (the CFRW map,
#: the entry search, the placed needles' heads): their certificate loses at most 0.25 mm
#: to the gaps, and a 1-degree map of a liver phantom stays under a second.
STRAIGHT_NEAR_STEP_MM: float = 0.5
#: Clearances above gamma by more than this (mm) are certified as "at least" this: it
#: bounds the sphere tracing's work (steps of d - cap far from obstacles).
STRAIGHT_CAP_ABOVE_GAMMA_MM: float = 10.0
#: Spacing (mm) of the check's dense certificate: at most 0.025 mm below the sampled
#: minimum, so it sees between the planner's samples.
STRAIGHT_CHECK_STEP_MM: float = 0.05
#: Decimals (of a mm) of the points a multi-needle record holds (``multi.json``).
RECORD_DECIMALS: int = 6
#: How far above gamma (mm) the straight planners' map wants a direction's clearance:
#: rounding both ends to RECORD_DECIMALS moves every point of the segment by at most
#: sqrt(3) * 0.5e-6 = 0.87e-6 mm, so the rounded segment's true clearance stays above
#: gamma (its sphere-traced certificate is re-computed on the rounded points by the
#: planner before it accepts, since the trace's samples may move by more than that).
RECORD_ROUNDING_ALLOWANCE_MM: float = 1e-6

#: The closed loop stops once the estimated tip's certified clearance is below this (mm),
#: or half the plan's margin if that is less (:mod:`needlekit.execute.proximity`). On
#: Med-RAD lung 3's 100 checkpoint runs (margin 0.5 mm, the tip recorded every 0.25 mm)
#: every estimated tip that did not cross kept about 0.2 mm or more by that measure; the
#: one that crossed fell below 0.1 mm before its true tip did.
STOP_CLEARANCE_MM: float = 0.1
