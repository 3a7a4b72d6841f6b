"""Array-first measurement models: wheel sensors, Doppler radar (SPEC §1)."""
