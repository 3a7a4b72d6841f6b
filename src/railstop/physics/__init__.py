"""The plant (DESIGN rule 1): train dynamics, brake chain, traction; ``plant``: one train's step
built on them, for the line and the live plant."""
