"""``[reference]``: the body's meshes are its shape imaged under a known load.

::

    [reference]
    imaged_under = "sag"   # a manipulation of the body (gravity, typically)
    tolerance = 1e-5       # m: the re-loaded stress-free shape vs the imaged one
    max_iterations = 30
    steps = 10             # load steps of the first solve (the ramp)

Every mesh is then replaced by its stress-free shape
(:mod:`idbench_fem.models.rest_shape`), so that the truth and the models
start unloaded. Parsing only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from idbench_fem.bodies.reader import TableReader


@dataclass(frozen=True)
class ImagedShape:
    """What the ``[reference]`` table says (see the module)."""

    imaged_under: str
    tolerance: float = 1e-5
    max_iterations: int = 30
    steps: int = 10


def parse_reference(
    raw: Any, source: str, manipulations: tuple[str, ...]
) -> ImagedShape | None:
    """The ``[reference]`` table, or None without one.

    Raises
    ------
    ValueError
        One line naming the bad value (an unknown manipulation, say).
    """
    if raw is None:
        return None
    c = TableReader(source, "[reference]")
    if not isinstance(raw, dict):
        raise c.error("must be a table with imaged_under = MANIPULATION")
    c.keys(raw, ("imaged_under", "tolerance", "max_iterations", "steps"))
    name = raw.get("imaged_under")
    if name not in manipulations:
        raise c.error(
            f"imaged_under = {name!r}: need a manipulation of this body "
            f"({', '.join(manipulations)})"
        )
    tol = c.number("tolerance", raw.get("tolerance", 1e-5), positive=True)
    counts = []
    for key, default in (("max_iterations", 30), ("steps", 10)):
        n = raw.get(key, default)
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise c.error(f"{key} = {n!r}: need a whole number >= 1")
        counts.append(n)
    return ImagedShape(str(name), tol, counts[0], counts[1])
