"""The finite-element engine (imports no other folder of the plugin).

Kernels, assembly per law, materials, Newton, linear solvers, chord iterations,
path steps, batched steps (predictions, pending pairs, step-worker processes),
interpolation.
"""
