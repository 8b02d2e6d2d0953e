"""The rotation check behind every pose argument (needlekit._validation): numpy for small
batches (no numba loaded to read a pose file), the numba kernel for large ones, the same
figures either way."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from needlekit import _validation
from needlekit._validation_kernels import rotation_errors
from needlekit.errors import InvalidInputError


def _near_rotations(n, seed, noise):
    rng = np.random.default_rng(seed)
    rot = Rotation.random(n, random_state=seed).as_matrix()
    rot += noise * rng.normal(size=rot.shape)
    rot[::7] *= -1.0  # reflections: det -1
    return np.ascontiguousarray(rot)


@pytest.mark.parametrize("noise", [0.0, 1e-9, 1e-3])
def test_numpy_and_kernel_give_the_same_errors(noise):
    rot = _near_rotations(50, 3, noise)
    small = _validation._rotation_errors(rot)  # below the kernel's batch size
    big = rotation_errors(rot)
    for a, b in zip(small, big, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)
    assert _validation._KERNEL_MIN_BATCH > len(rot)


def test_both_paths_refuse_the_same_item():
    for n in (5, 2 * _validation._KERNEL_MIN_BATCH):
        rot = _near_rotations(n, 4, 0.0)
        rot[::7] *= -1.0  # undo the reflections
        poses = np.tile(np.eye(4), (n, 1, 1))
        poses[:, :3, :3] = rot
        _validation.as_poses(poses, "pose")
        poses[3, 0, 0] += 1e-3
        with pytest.raises(InvalidInputError, match=r"^pose: rotation part of item 3 "):
            _validation.as_poses(poses, "pose")
