"""A plan carried out: a simulated bevel-tip needle that does not follow its model, a
tracked tip, a pose estimator, a feedback law that steers back to the plan, and
re-planning from where the tip is (docs/execute.md).

Modules
-------
needle_sim
    The needle and the tissue: the unicycle model with process noise, a curvature that
    is not the nominal one, and tissue that deflects the tip.
estimator
    A Kalman filter on the tip pose, fed by delayed EM samples.
feedback
    The plan as a reference path, and the pure-pursuit law that steers toward it.
"""
