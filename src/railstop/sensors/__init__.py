"""Measurement models: wheel sensors (SPEC §1); tachometer, odometer, track circuits, GNSS clock (SPEC §2)."""
