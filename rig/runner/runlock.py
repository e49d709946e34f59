"""An exclusive lock on a run, so two processes never drive the same run (docs/design.md §5).

`OUT/RUN_ID.lock` is `flock`ed for as long as one invocation works on the run and holds that
process's id, for the refusal message. The kernel drops a `flock` when its process dies, so a
crashed (even SIGKILLed) run leaves at most an unlocked file, which the next invocation takes over.
A released lock removes its file while still holding it; `acquire` checks that the file it locked
is still the one at the path, so it never holds a lock on a file that was just removed.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from rig.errors import InputError


class RunInProgressError(InputError):
    """The run is locked by another invocation (another process, or this one)."""


class RunLock:
    """A held lock on one run; `release()` (idempotent) gives it up."""

    def __init__(self, path: Path, fd: int) -> None:
        self.path = path
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, path: Path, run_id: str) -> RunLock:
        """Lock `path` without waiting; `RunInProgressError` if someone holds it, OSError if unwritable."""
        while True:
            # 0o666 less the umask, as open() makes a file: a lab group sharing runs can lock it too.
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(fd)
                os.close(fd)
                raise RunInProgressError(
                    f"run {run_id} is in progress in {holder} (lock {path}); "
                    "wait for it to end, or stop it, before resuming"
                ) from None
            except BaseException:
                os.close(fd)
                raise
            if _same_file(fd, path):
                break
            os.close(fd)  # its holder removed it after we opened it: lock the file now at the path
        with contextlib.suppress(OSError):  # without the pid the lock holds; only messages lack it
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        return cls(path, fd)

    @property
    def held(self) -> bool:
        """Whether this object still holds the lock."""
        return self._fd is not None

    def release(self) -> None:
        """Remove the lock file and unlock it (in that order; see the module docstring)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            with contextlib.suppress(OSError):  # an unlocked file left behind blocks nobody
                self.path.unlink(missing_ok=True)
        finally:
            os.close(fd)


def _holder(fd: int) -> str:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        text = ""
    return f"process {text}" if text.isdigit() else "another process"


def _same_file(fd: int, path: Path) -> bool:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)
