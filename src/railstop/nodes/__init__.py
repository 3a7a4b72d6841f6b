"""Nodes: the units of one place (a train at a platform, a zone controller) built once from the
line data and wired; the same objects run in simulation, in the verifiers and live."""
