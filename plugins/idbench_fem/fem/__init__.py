"""The finite-element engine (imports no other folder of the plugin).

Kernels, assembly per law, materials, Newton, linear solvers, batched steps,
step-worker processes, interpolation.
"""
