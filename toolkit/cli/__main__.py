"""``python -m tendonkit.cli``: the same as the ``tendonkit`` command."""

from __future__ import annotations

import sys

from . import main

sys.exit(main())
