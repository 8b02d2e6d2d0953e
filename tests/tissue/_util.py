"""Small meshes and the closed forms the tissue tests compare against."""

import numpy as np

from needlekit.tissue.meshing import mesh_mask


def cube_mesh(n: int, half: float = 1.0):
    """The cube [-half, half]^3 in n^3 cells (six tetrahedra each)."""
    h = 2.0 * half / n
    aff = np.diag([h, h, h, 1.0])
    aff[:3, 3] = -half + h / 2
    return mesh_mask(np.ones((n, n, n), bool), aff, cell_mm=h)
