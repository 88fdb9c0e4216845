"""Type hints of the native module (written by hand beside python/src/lib.rs)."""

from __future__ import annotations

from os import PathLike
from typing import Any, ClassVar, Mapping, Union

import numpy as np
import numpy.typing as npt

Deck = Union[str, "PathLike[str]", Mapping[str, Any]]

__version__: str

class DeckError(ValueError):
    """The deck is wrong; the message names the key."""

class SolverError(RuntimeError):
    """The run blew up: a NaN, or a particle left the grid."""

class Simulation:
    """A simulation built from a deck (a file path or a dict), stepped from Python."""

    particle_fields: ClassVar[list[str]]
    grid_fields: ClassVar[list[str]]

    def __init__(
        self,
        deck: Deck,
        *,
        base_dir: Union[str, "PathLike[str]", None] = None,
        threads: int | None = None,
        allow_large: bool = False,
    ) -> None: ...
    @property
    def time(self) -> float:
        """Simulated time (s)."""
    @property
    def steps(self) -> int:
        """Steps taken."""
    @property
    def dimension(self) -> int:
        """2 or 3."""
    @property
    def end_time(self) -> float:
        """The deck's end time (s)."""
    @property
    def particle_count(self) -> int:
        """Number of particles now."""
    @property
    def cell_size(self) -> float:
        """The grid's cell size h (m)."""
    @property
    def grid_coordinates(self) -> tuple[npt.NDArray[np.float64], ...]:
        """Node positions along each axis (m), the axes of ``grid_field``."""
    @property
    def deck(self) -> dict[str, Any]:
        """The checked deck, every default filled in."""
    def mass_balance(self) -> float:
        """(m0 + m_in - m_out - m(t)) / (m0 + m_in): round-off."""
    def step(self) -> float:
        """One step of the deck's size; returns its size (s)."""
    def run(self, until: float | None = None) -> int:
        """Steps to ``until`` (the deck's end time by default); returns the steps taken."""
    def particle_field(self, name: str) -> npt.NDArray[Any]:
        """A copy of a particle field, one row per particle in id order."""
    def grid_field(self, name: str) -> npt.NDArray[np.float64]:
        """A node field indexed [i, j(, k)] with i along x."""

def run(
    deck: Deck,
    output: Union[str, "PathLike[str]", None] = None,
    *,
    force: bool = False,
    base_dir: Union[str, "PathLike[str]", None] = None,
    threads: int | None = None,
    allow_large: bool = False,
    resume: Union[str, "PathLike[str]", None] = None,
) -> dict[str, Any]:
    """Runs a deck to its end into a run directory, as ``pmpm run`` does; returns the summary."""

def read_deck(path: Union[str, "PathLike[str]"]) -> dict[str, Any]:
    """A deck file's keys as written, to change and run."""
