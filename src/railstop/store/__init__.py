"""The event database: stations, stops, their command history and results (SPEC §1 claims 8, 20)."""

from __future__ import annotations

from railstop.store.db import (
    COMMAND_FIELDS,
    DEFAULT_BUSY_TIMEOUT_S,
    RESULT_FIELDS,
    SCHEMA_VERSION,
    SENT_FIELDS,
    STATION_FIELDS,
    StationRecord,
    StopRecord,
    Store,
    StoreCorrupt,
    StoreError,
    StoreUnavailable,
    office_report_values,
    open_store,
)

__all__ = [
    "COMMAND_FIELDS",
    "DEFAULT_BUSY_TIMEOUT_S",
    "RESULT_FIELDS",
    "SCHEMA_VERSION",
    "SENT_FIELDS",
    "STATION_FIELDS",
    "StationRecord",
    "StopRecord",
    "Store",
    "StoreCorrupt",
    "StoreError",
    "StoreUnavailable",
    "office_report_values",
    "open_store",
]
