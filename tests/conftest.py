"""``tests`` is a package (``tests.hdl.streams`` imports by name); the flat helper modules
next to the tests (``wavefront_model``, ``sim_frames``, ...) are still imported by bare
name, so their folder stays on ``sys.path`` until they move into packages."""

import sys
from pathlib import Path

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)
