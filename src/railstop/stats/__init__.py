"""Statistics: confidence bounds and the campaign summary."""
