"""Array-first control laws: ground TASC, notch modulation."""
