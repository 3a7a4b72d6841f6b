"""Pure units on the train: the onboard TASC receiver (SPEC §1)."""
