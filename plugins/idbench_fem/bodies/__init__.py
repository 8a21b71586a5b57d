"""What is simulated (imports only :mod:`idbench_fem.fem`).

Meshes (the general tetrahedral one, the structured box), the body description
(TOML), the shipped bodies, region selectors, loads, gmsh geometry.
"""
