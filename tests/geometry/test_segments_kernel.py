"""The one-pair numba kernel of the closest points (``closest_segment_params``, shared by
the phantoms' capsule clearance and the placed-needle VFIs) against the batch form
``segment_distances``, degenerate segments included."""

import numpy as np

from needlekit.geometry.segments import closest_segment_params, segment_distances


def test_the_pair_kernel_gives_the_batch_form_s_distance():
    rng = np.random.default_rng(4)
    for k in range(500):
        p0, p1 = rng.normal(size=3) * 20, rng.normal(size=3) * 20
        q0, q1 = rng.normal(size=3) * 20, rng.normal(size=3) * 20
        if k % 5 == 1:
            p1 = p0.copy()  # a point
        if k % 5 == 2:
            q1 = q0.copy()
        if k % 5 == 3:
            p1, q1 = p0.copy(), q0.copy()
        if k % 5 == 4:
            q1 = q0 + 2.0 * (p1 - p0)  # parallel
        d1, d2 = p1 - p0, q1 - q0
        s, t = closest_segment_params(*(p0 - q0), *d1, *d2)
        assert 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
        got = np.linalg.norm(p0 + s * d1 - q0 - t * d2)
        want = segment_distances(p0, p1, q0[None], q1[None])[0]
        assert abs(got - want) <= 1e-9 * max(1.0, want)
