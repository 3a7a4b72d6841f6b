"""The plant (DESIGN rule 1): train dynamics, brake chain, traction."""
