"""Robot puncture control (Tang et al.): Panda model, vector-field inequalities, QP controller."""
