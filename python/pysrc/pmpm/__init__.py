"""pmpm: the projection-method material point method solver, from Python.

Load a deck (a file or a dict), step it or run it to a time, and read its particle and grid
fields as NumPy arrays::

    import pmpm
    sim = pmpm.Simulation("examples/dam_break_2d.toml")
    sim.run(until=0.2)
    x = sim.particle_field("position")        # (n, 2), in particle id order
    p = sim.grid_field("pressure")            # (nx, ny), node [i, j] at origin + (i, j) h

``pmpm.run(deck, output)`` writes a run directory as ``pmpm run`` does. A sweep reads a deck
once with ``read_deck``, and gives ``with_changes(deck, {...})`` of it to each run.
"""

from __future__ import annotations

import copy
from typing import Any, Mapping

from ._pmpm import DeckError, Simulation, SolverError, __version__, read_deck, run

__all__ = [
    "DeckError",
    "Simulation",
    "SolverError",
    "__version__",
    "read_deck",
    "run",
    "with_changes",
]


def with_changes(deck: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of ``deck`` with ``changes`` applied, each keyed by its dotted path.

    A path names tables by key and arrays of tables by index, as the deck's error messages
    do: ``"simulation.end_time"``, ``"materials[0].viscosity"``, ``"grid.cell_size"``. A
    missing table on the way is created; an index past an array's end raises ``KeyError``.
    The deck given is left as it was.
    """
    out = copy.deepcopy(dict(deck))
    for path, value in changes.items():
        parts = _split(path)
        node: Any = out
        for here, step in enumerate(parts[:-1]):
            node = _child(node, step, parts[: here + 1], path, create=True)
        last = parts[-1]
        if isinstance(last, int):
            _child(node, last, parts, path, create=False)  # checks the index
        node[last] = copy.deepcopy(value)
    return out


def _split(path: str) -> list[str | int]:
    """``"materials[0].viscosity"`` -> ``["materials", 0, "viscosity"]``."""
    parts: list[str | int] = []
    for name in path.split("."):
        while "[" in name:
            head, _, rest = name.partition("[")
            index, _, name = rest.partition("]")
            if head:
                parts.append(head)
            if not index.isdigit():
                raise KeyError(f"{path}: {index!r} is not an array index")
            parts.append(int(index))
        if name:
            parts.append(name)
    if not parts:
        raise KeyError(f"{path!r}: an empty key")
    return parts


def _child(node: Any, step: str | int, so_far: list[str | int], path: str, create: bool) -> Any:
    if isinstance(step, int):
        if not isinstance(node, list) or step >= len(node):
            raise KeyError(f"{path}: there is no entry {step} there")
        return node[step]
    if not isinstance(node, dict):
        raise KeyError(f"{path}: {so_far[:-1]} is not a table")
    if step not in node and create:
        node[step] = {}
    return node[step]
