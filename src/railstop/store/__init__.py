"""The event database: stops, their command history and their results (SPEC §1 claims 8, 20)."""

from __future__ import annotations

from railstop.store.db import COMMAND_FIELDS, RESULT_FIELDS, StopRecord, Store, open_store

__all__ = ["COMMAND_FIELDS", "RESULT_FIELDS", "StopRecord", "Store", "open_store"]
