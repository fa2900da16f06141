"""File I/O: writing that never leaves a half-written file under the final name; JSON reading with clear errors."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable

from pegasus_gen.errors import PegasusError


def umask() -> int:
    """The process's file-mode creation mask (from /proc where it shows, without changing it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def give_default_mode(path: str | os.PathLike, directory: bool = False) -> None:
    """Give ``path`` the mode a plain ``open``/``mkdir`` would have (0666/0777 less the umask): tempfile makes
    its files 0600 and folders 0700, which renaming them into place would keep."""
    os.chmod(path, (0o777 if directory else 0o666) & ~umask())


def write_atomic(path: str | os.PathLike, write: Callable[[BinaryIO], None]) -> Path:
    """Create ``path`` by calling ``write(f)`` on a temporary file beside it, then renaming it into place (with
    the mode the umask gives a new file).

    On any error the temporary file is removed and an existing file at ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        give_default_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def link_atomic(source: str | os.PathLike, path: str | os.PathLike) -> Path:
    """Make ``path`` another name of the file ``source`` (a hard link, so nothing is written twice; a copy where
    the file system has no hard links), replacing an existing ``path`` in one step."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        os.unlink(tmp)
        try:
            os.link(source, tmp)
        except OSError:
            shutil.copyfile(source, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def parse_yaml(text: str, what: str):
    """``text`` parsed as YAML (safe: plain data only); a PegasusError naming ``what`` and the first line of the
    problem when it is not YAML (e.g. an unclosed ``[``)."""
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).strip().splitlines()[0]
        mark = getattr(exc, "problem_mark", None)
        where = f" at column {mark.column + 1}" if mark is not None and mark.line == 0 else \
            (f" at line {mark.line + 1}" if mark is not None else "")
        raise PegasusError(f"{what}: not valid YAML ({problem}{where})") from None


def read_json(path: str | os.PathLike):
    """The parsed JSON file at ``path``; a missing or malformed file is a PegasusError naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except OSError:
        raise PegasusError(f"{path}: missing or unreadable") from None
    except json.JSONDecodeError as exc:
        raise PegasusError(f"{path}: not valid JSON ({exc})") from None
