"""One writer per output folder: an advisory lock (``fcntl.flock``) on ``FOLDER/.lock``, held for the whole run.

A second writer is refused at once, told who holds it (what and pid, written in the file). The lock file is
created by the run that holds it (``O_CREAT | O_EXCL | O_NOFOLLOW``: never a symlink followed, never another
file truncated) and removed when the run ends, refused or not; the folders the lock had to create are removed
again when they are left empty. The kernel drops the lock with the process that holds it, so the ``.lock``
a killed run leaves behind is stale: the next run takes it over (when it is a plain file with no other name)
and removes it in turn.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from pathlib import Path

from pegasus_gen.errors import PegasusError

LOCK_FILE = ".lock"


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and those of its parents that do not exist yet, deepest first."""
    missing = []
    for path in (folder, *folder.parents):
        if path.exists() or path.is_symlink():
            break
        missing.append(path)
    return missing


class FolderLock:
    """``with FolderLock(folder):`` the folder (created if missing) is this process's to write."""

    def __init__(self, folder: str | os.PathLike, what: str = "a run"):
        self.folder, self.what, self.fd, self.created = Path(folder), what, None, []

    @property
    def path(self) -> Path:
        return self.folder / LOCK_FILE

    def __enter__(self) -> "FolderLock":
        if self.folder.exists() and not self.folder.is_dir():
            raise PegasusError(f"{self.folder}: exists and is not a folder")
        self.created = _missing_folders(self.folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.fd = self._acquire()
            os.write(self.fd, f"{self.what} (pid {os.getpid()})".encode())
        except OSError as exc:
            self.__exit__()
            raise PegasusError(f"{self.folder}: cannot write there ({exc.strerror})") from None
        except BaseException:
            self.__exit__()
            raise
        return self

    def _acquire(self) -> int:
        """A descriptor of a lock file this call created and locked (a stale one found there is removed first)."""
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666)
                created = True
            except FileExistsError:
                fd, created = self._open_existing(), False
                if fd is None:  # removed meanwhile by the run that held it
                    continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 256, 0).decode(errors="replace").strip() or "another process"
                os.close(fd)
                raise PegasusError(f"{self.folder} is being written by {holder}; wait for it to end or choose "
                                   "another folder") from None
            if self._still_named(fd):
                if created:
                    return fd
                os.unlink(self.path)  # stale (its run has ended) and now ours: made afresh on the next turn
            os.close(fd)  # another run removed or replaced it meanwhile: try again

    def _open_existing(self) -> int | None:
        """The existing lock file opened without following a symlink (None if it is gone); refused when it is
        not a plain file with one name (it could be someone else's)."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_NOFOLLOW)
        except FileNotFoundError:
            return None
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise PegasusError(f"{self.path} is a symbolic link, not a lock file; remove it") from None
            raise
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_nlink != 1:
            os.close(fd)
            raise PegasusError(f"{self.path} is not a lock file (not a plain file with one name); remove it")
        return fd

    def _still_named(self, fd: int) -> bool:
        """Whether the lock file's name still leads to the file ``fd`` has open."""
        try:
            named = os.lstat(self.path)
        except FileNotFoundError:
            return False
        held = os.fstat(fd)
        return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)

    def _remove_created(self) -> None:
        """Remove the folders this lock created, deepest first, as long as they are empty."""
        for folder in self.created:
            try:
                folder.rmdir()
            except FileNotFoundError:  # never made: mkdir failed on the way
                continue
            except OSError:  # not empty: it holds the run's work
                return

    def __exit__(self, *exc) -> None:
        """Remove the lock file (while still locked: a run waiting on it then sees it is gone), release the
        lock, and remove the folders the lock created if they are left empty."""
        if self.fd is not None:
            if self._still_named(self.fd):
                os.unlink(self.path)
            os.close(self.fd)  # closing the last descriptor releases the lock
            self.fd = None
        self._remove_created()
