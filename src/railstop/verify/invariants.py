"""What the exhaustive checks share (``doors verify``, ``zones verify``, ``platform verify``):
an invariant as data and a violation with its trace."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

C = TypeVar("C")


@dataclass(frozen=True, slots=True, kw_only=True)
class Invariant(Generic[C]):
    """A named rule with its text and its check (a plain function; its arguments are the
    verifier's own: a transition, the model...)."""

    name: str
    text: str
    check: C
    # False: the check does not read the inputs, so a verifier over input combinations may run it
    # once for all the combinations that lead from one state to the same next state.
    per_input: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class Violation:
    """The first counterexample of an invariant: why, and the path to it from an initial state."""

    invariant: str
    message: str
    trace: tuple[str, ...]


class Verification(Protocol):
    """What every exhaustive check returns: the size of the search, the violating transitions
    per invariant, the first counterexample of each, and how long it took."""

    @property
    def states(self) -> int: ...
    @property
    def transitions(self) -> int: ...
    @property
    def violations(self) -> int: ...
    @property
    def counts(self) -> Mapping[str, int]: ...
    @property
    def examples(self) -> Sequence[Violation]: ...
    @property
    def elapsed_s(self) -> float: ...
