"""Array-first plant (DESIGN rule 1): train dynamics, brake chain, wheel and tachometer."""
