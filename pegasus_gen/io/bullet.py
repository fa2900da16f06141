"""pybullet, imported with its build banner silenced: its C module writes "pybullet build time: ..." to stderr
when first imported, which would precede every error line of a command (and of the simulated controller)."""

from __future__ import annotations

import os
import sys


def quiet_pybullet():
    """The pybullet module, imported (the first time) with file descriptor 2 pointed at /dev/null."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return pybullet
