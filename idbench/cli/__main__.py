"""``python -m idbench.cli``: the ``idbench`` command."""

import sys

from idbench.cli.commands import main

sys.exit(main())
