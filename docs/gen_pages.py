"""Writes the generated pages at build time (mkdocs-gen-files).

The home page from README.md, the layout of the code, the API reference and
the hook sections of ``reference/hooks.md``; the text comes from
``docs/pages.py``, which the tests in ``tests/docs/`` read too.
"""

from __future__ import annotations

import sys
from pathlib import Path

import mkdocs_gen_files

sys.path.insert(0, str(Path(__file__).resolve().parent))

import pages  # docs/ is not a package: on the path above

for path, text in pages.iter_pages():
    with mkdocs_gen_files.open(path, "w") as page:
        page.write(text)

with mkdocs_gen_files.open("reference/hooks.md", "a") as page:  # after its intro
    page.write("\n" + pages.hook_sections())
