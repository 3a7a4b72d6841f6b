"""Drivers: the single detailed stop and the batch engine under it."""
