"""Pure units on the ground: the ground TASC unit (SPEC §1)."""
