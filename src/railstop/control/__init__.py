"""Control laws: ground TASC and notch modulation (compiled scalar cores), run profile, doors."""
