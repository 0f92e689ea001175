"""The bounded-reader tests and the CLI fuzz test share the bad-input corpus (badfiles.py)."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
