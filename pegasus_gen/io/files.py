"""File I/O: writing that never leaves a half-written file under the final name; JSON reading with clear errors."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

from pegasus_gen.errors import PegasusError


def write_atomic(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> Path:
    """Create ``path`` by calling ``write(f)`` on a temporary file beside it, then renaming it into place.

    On any error the temporary file is removed and an existing file at ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_json(path: str | os.PathLike):
    """The parsed JSON file at ``path``; a missing or malformed file is a PegasusError naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except OSError:
        raise PegasusError(f"{path}: missing or unreadable") from None
    except json.JSONDecodeError as exc:
        raise PegasusError(f"{path}: not valid JSON ({exc})") from None
