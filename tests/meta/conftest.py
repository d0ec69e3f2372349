"""The meta-tests import their checkers (tests/meta/rooms.py) as a plain module."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
