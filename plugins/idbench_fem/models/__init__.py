"""The forward models: the solid, the SVK beam, their settings and scenarios.

They import :mod:`idbench_fem.bodies` and :mod:`idbench_fem.fem`.
"""
