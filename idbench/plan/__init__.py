"""What is asked and whether it can be run.

The comparison's config, run descriptions and the checks at the door that
turn a config into a :class:`~idbench.plan.check.Plan`.
"""
