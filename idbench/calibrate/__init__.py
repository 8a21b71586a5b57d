"""A coarse mesh against a finer one.

Effective parameters along a path and the approximation-error correction
(the tissue's E rather than the mesh's).
"""
