"""The event database: stations, stops, their command history and results (SPEC §1 claims 8, 20)."""

from __future__ import annotations

from railstop.store.db import (
    COMMAND_FIELDS,
    RESULT_FIELDS,
    SCHEMA_VERSION,
    SENT_FIELDS,
    STATION_FIELDS,
    StationRecord,
    StopRecord,
    Store,
    open_store,
)

__all__ = [
    "COMMAND_FIELDS",
    "RESULT_FIELDS",
    "SCHEMA_VERSION",
    "SENT_FIELDS",
    "STATION_FIELDS",
    "StationRecord",
    "StopRecord",
    "Store",
    "open_store",
]
