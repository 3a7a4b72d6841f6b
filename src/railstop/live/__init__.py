"""Drivers on wall-clock time: the management office, its page, the live runner (DESIGN: live/)."""
