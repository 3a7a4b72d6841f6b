"""The error hierarchy (DESIGN rule 6): every message names the field and the bad value."""

from __future__ import annotations


class RailstopError(Exception):
    """Base of every error railstop raises on purpose."""


class ConfigError(RailstopError, ValueError):
    """A data file (line, vehicle, disturbances) is invalid.

    ``str(error)`` is one line: ``file: field.path: message (got value)``.
    """

    def __init__(self, source: str, field: str, message: str, value: object = None) -> None:
        self.source = source
        self.field = field
        self.message = message
        self.value = value
        got = "" if value is None else f" (got {_shown(value)})"
        super().__init__(f"{source}: {field}: {message}{got}")


# The longest value a message quotes whole: a longer one (a whole list of track circuits, a table)
# is cut, with its size, so that the message stays one readable line.
SHOWN_VALUE_CHARS = 160


def _shown(value: object) -> str:
    text = repr(value)
    if len(text) <= SHOWN_VALUE_CHARS:
        return text
    size = f", {len(value)} items in all" if isinstance(value, (list, tuple, dict)) else ""
    return f"{text[: SHOWN_VALUE_CHARS - 40]}... ({len(text)} characters{size})"


class TelegramError(RailstopError):
    """A telegram could not be decoded; ``reason`` is a short machine-readable code."""

    def __init__(self, reason: str, detail: str = "") -> None:
        self.reason = reason
        self.detail = detail
        super().__init__(f"{reason}: {detail}" if detail else reason)


class InterlockError(RailstopError):
    """A state machine received an input its transition table does not allow."""


class SimulationError(RailstopError):
    """A simulation could not be set up from the given inputs (e.g. unknown station)."""
