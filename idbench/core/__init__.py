"""The core's vocabulary.

Protocols and value types, scenarios, a model's optional members, the rules
of settings, safe text and the version. Every other room may import it; it
imports nothing above it.
"""
