"""What several test modules share: toy models, helpers, oracles, fixtures' pieces.

Test modules import from here (``from support.toymodels import LinearToy``),
never from one another; ``tests/`` is on ``sys.path`` (see ``conftest.py``).
"""
