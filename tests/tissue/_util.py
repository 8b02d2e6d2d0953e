"""Small meshes and the closed forms the tissue tests compare against."""

import numpy as np

from needlekit.tissue.meshing import mesh_mask


def cube_mesh(n: int, half: float = 1.0):
    """The cube [-half, half]^3 in n^3 cells (six tetrahedra each)."""
    h = 2.0 * half / n
    aff = np.diag([h, h, h, 1.0])
    aff[:3, 3] = -half + h / 2
    return mesh_mask(np.ones((n, n, n), bool), aff, cell_mm=h)


def kelvin(x, force, mu: float, nu: float):
    """Kelvin's displacement (mm) at ``x`` of a point force ``force`` (N) at the origin of
    an infinite body: u = F/(16 pi mu (1-nu) r) [(3-4nu) I + r_hat r_hat] . F_hat."""
    r = np.linalg.norm(x, axis=1)[:, None]
    rh = x / r
    return (force[None, :] * (3 - 4 * nu) + rh * (rh @ force)[:, None]) / (
        16 * np.pi * mu * (1 - nu) * r
    )
