"""One writer per output folder: an advisory lock (``fcntl.flock``) on ``FOLDER/.lock``, held for the whole run.

A second writer is refused at once, told who holds it (what and pid, written in the file). The kernel drops
the lock with the process that holds it, so a killed run leaves no stale lock behind (the ``.lock`` file
stays; it means nothing alone).
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from pegasus_gen.errors import PegasusError

LOCK_FILE = ".lock"


class FolderLock:
    """``with FolderLock(folder):`` the folder (created if missing) is this process's to write."""

    def __init__(self, folder: str | os.PathLike, what: str = "a run"):
        self.folder, self.what, self.fd = Path(folder), what, None

    def __enter__(self) -> "FolderLock":
        if self.folder.exists() and not self.folder.is_dir():
            raise PegasusError(f"{self.folder}: exists and is not a folder")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.folder / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise PegasusError(f"{self.folder}: cannot write there ({exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 256, 0).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise PegasusError(f"{self.folder} is being written by {holder}; wait for it to end or choose another "
                               "folder") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{self.what} (pid {os.getpid()})".encode(), 0)
        self.fd = fd
        return self

    def __exit__(self, *exc) -> None:
        os.ftruncate(self.fd, 0)
        os.close(self.fd)  # closing the last descriptor releases the lock
        self.fd = None
