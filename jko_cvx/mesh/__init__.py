"""Adaptive mesh refinement (``sec:mr``): the mesh maps, PCHIP remapping and moment restoration."""
