"""Verifiers: exhaustive explorers of the door, platform and zone models and their invariants."""
