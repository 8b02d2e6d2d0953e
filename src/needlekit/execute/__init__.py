"""A plan carried out: a simulated bevel-tip needle that does not follow its model, a
tracked tip, a pose estimator, a feedback law that steers back to the plan, and
re-planning from where the tip is; and the trials of ``needlekit execute`` with their
records (docs/execute.md).

Modules
-------
run
    One insertion, open loop or closed loop: the loop.
plugins
    The plug points: the protocols of the truth, the tip sensor, the estimator and the
    feedback law, and their registries (``--truth``, ``--sensor``, ``--estimator``,
    ``--feedback``).
needle_sim, tissue_layers
    The truths: the unicycle with process noise, a curvature that is not the nominal one
    and tissue that deflects the tip (``kinematic``); the same in layered tissue
    (``layered``).
sensors
    The tip sensors: the simulated EM sensor (``em``), a tracker over OpenIGTLink
    (``igtl``, through :mod:`igtl_link`).
estimator, unscented
    A Kalman filter on the tip pose, fed by delayed EM samples (``kalman``); its unscented
    counterpart (``unscented``).
feedback, sliding_mode
    The plan as a reference path; pure pursuit (``pure_pursuit``) and Rucker et al.'s
    sliding-mode law (``sliding_mode``).
replan
    Re-planning from the estimated tip by a planner declaring ``warm_start``.
guard, faults, breathing, igtl_link
    The sensor guard every sample passes, injected faults, the anatomy breathing, the
    live link to 3D Slicer.
proximity
    The closed loop's stop when the estimated tip comes too close to an obstacle.
tip_path
    The true tip's path as an insertion records it, in the world and at rest.
trials, trial_runs, record, summary
    The trials of ``needlekit execute``: the runner, the executor loop (Ctrl-C,
    ``--resume``), each trial's record and status, the study's summary.
"""
