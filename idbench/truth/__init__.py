"""The truth.

The fine mesh's load path simulated with the true parameters, and its disk
cache.
"""
