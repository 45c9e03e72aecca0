"""Test configuration: make the shared oracles in ``tests/oracles.py`` importable."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
