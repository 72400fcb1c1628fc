"""The user's cache folder, shared by every tool that keeps built artefacts (star databases,
MicroPython builds, co-simulation and place-and-route results), each in its own sub-folder."""

import os
from pathlib import Path


def default_cache_dir():
    """``$LODESTAR_CACHE_DIR``, else ``$XDG_CACHE_HOME/lodestar``, else
    ``~/.cache/lodestar``."""
    if os.environ.get("LODESTAR_CACHE_DIR"):
        return Path(os.environ["LODESTAR_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lodestar"
