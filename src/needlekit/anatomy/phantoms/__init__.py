"""Procedural phantoms: seeded lung, liver and neck scenes shipped with the package.

Every phantom is generated from a seed (no data files): the same seed gives the same
phantom bit for bit, other seeds different but equally valid ones. Each is built for
one of the procedures needlekit plans:

=========  =================================================  ==============================
name       procedure                                          module
=========  =================================================  ==============================
``lung``   transbronchial needle aspiration, curved needle    :mod:`.lung`
           from the airway wall to a nodule (Feng 2023)
``liver``  straight ablation needles from the skin between    :mod:`.liver`
           the ribs to a tumour (Liu 2016)
``neck``   percutaneous tracheostomy: a guide line from the   :mod:`.neck`
           skin between two tracheal rings (Tang)
=========  =================================================  ==============================

Geometry is described exactly (:mod:`._shapes`: tapered tubes, sheets, balls and
half-spaces; :mod:`._trees`: space-filling vessel and airway trees, grown from the tubes
of :mod:`._tubes`) and the complex structures are baked into voxel distance grids. Builds are cached per (name, seed,
voxel size) in the process.

Examples
--------
>>> from needlekit.anatomy.phantoms import make_phantom
>>> neck = make_phantom("neck", seed=3)  # doctest: +SKIP
>>> neck.scene.names  # doctest: +SKIP
['skin', 'trachea_lumen', 'tracheal_rings', 'thyroid', 'vessels', 'oesophagus', 'spine']
"""

from __future__ import annotations

import inspect

from needlekit.anatomy.phantoms._shapes import Phantom
from needlekit.anatomy.phantoms.liver import liver_phantom
from needlekit.anatomy.phantoms.lung import lung_phantom
from needlekit.anatomy.phantoms.neck import neck_phantom
from needlekit.errors import InvalidInputError

__all__ = ["PHANTOMS", "Phantom", "liver_phantom", "lung_phantom", "make_phantom", "neck_phantom"]

#: The phantoms by name.
PHANTOMS = {"lung": lung_phantom, "liver": liver_phantom, "neck": neck_phantom}


def make_phantom(name: str, seed: int = 0, **kw) -> Phantom:
    """Build (or fetch from the cache) a phantom by name.

    Parameters
    ----------
    name : str
        One of ``"lung"``, ``"liver"``, ``"neck"``.
    seed : int
        Seed (>= 0).
    **kw
        Passed to the phantom's function (e.g. ``voxel_size_mm``).

    Returns
    -------
    Phantom

    Raises
    ------
    InvalidInputError
        Unknown name (the message lists the valid ones), bad seed or keyword values.

    Examples
    --------
    >>> make_phantom("kidney")
    Traceback (most recent call last):
    ...
    needlekit.errors.InvalidInputError: name: unknown phantom 'kidney'; expected one of lung, liver, neck
    """
    try:
        build = PHANTOMS[name]
    except (KeyError, TypeError):
        valid = ", ".join(PHANTOMS)
        raise InvalidInputError(
            "name", f"unknown phantom {name!r}; expected one of {valid}"
        ) from None
    allowed = [
        k
        for k, p in inspect.signature(build).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    for key in kw:
        if key not in allowed:
            raise InvalidInputError(
                key, f"not an option of the {name} phantom; expected one of {', '.join(allowed)}"
            )
    return build(seed, **kw)
