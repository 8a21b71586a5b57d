"""The filters plugin's modules: public names, no reach into private ones."""

from __future__ import annotations

from pathlib import Path

from support.namespace import private_reaches

import idbench_filters

PACKAGE = Path(idbench_filters.__file__).resolve().parent


def test_no_module_is_private_or_reaches_into_private_names():
    assert not [p.name for p in PACKAGE.glob("_*.py") if p.name != "__init__.py"]
    assert private_reaches(PACKAGE) == []
