"""Perception: one RGB-D frame → geometric primitives, spatial and support graph, affordances
(thesis Ch. 3.1-3.2)."""
