"""The plugins.

Hook specs, the plugin manager and its registry, the conformance checks a
plugin author runs (:mod:`idbench.registry.testing`) and settings info.
"""
