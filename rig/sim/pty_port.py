"""A pseudo-terminal that stands in for a serial device, reachable through a symlink.

Used by `rig sim servos` and `rig sim loadcell`: the emulator owns the master side, a client
opens the symlink with pyserial as if it were `/dev/ttyUSB0`. Hygiene (see docs/design.md §7):
the slave is put in raw mode before any client opens it (else ECHO reflects the emulator's
replies back to it) and kept open here so that a client's `close()` does not make the master's
reads fail with EIO.

A client opening the port is what resets an Arduino-class board (pyserial asserts DTR on open).
A pty has no modem lines (pyserial's DTR ioctl fails there and it ignores that), and the master
side sees nothing of an open while this module holds the slave open. So `ClientOpens` watches
the slave's device node with Linux inotify (IN_OPEN, IN_CLOSE_WRITE, IN_CLOSE_NOWRITE, through
the C library): every open(2) of it by another process is an event, whichever path it came by
(the symlink resolves to the node). This module's own descriptor was opened before the watch and
its tcgetattr calls open nothing. Where inotify is missing (not Linux) the watch is unavailable
and an emulator cannot tell that a client opened the port.
"""

from __future__ import annotations

import contextlib
import ctypes
import enum
import errno
import os
import pty
import signal
import struct
import sys
import termios
import tty
from pathlib import Path
from types import FrameType, TracebackType

from rig.errors import InputError

# termios speed constants -> baud rate in bit/s, for reading the client's configured speed.
_SPEEDS: dict[int, int] = {
    getattr(termios, f"B{b}"): b
    for b in (
        9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
        1000000, 1152000, 1500000, 2000000, 2500000, 3000000, 3500000, 4000000,
    )
    if hasattr(termios, f"B{b}")
}  # fmt: skip


# inotify(7): the event masks, the non-blocking flag of inotify_init1, and `struct inotify_event`.
_IN_CLOSE_WRITE = 0x00000008
_IN_CLOSE_NOWRITE = 0x00000010
_IN_OPEN = 0x00000020
_IN_NONBLOCK = os.O_NONBLOCK
_EVENT_HEADER = struct.Struct("iIII")  # wd, mask, cookie, len (then len bytes of name)


class ClientEvent(enum.Enum):
    """What a client did to the slave side."""

    OPENED = "opened"
    CLOSED = "closed"


class ClientOpens:
    """Opens and closes of a pty's slave device by other processes (Linux inotify; see the module)."""

    def __init__(self, device_path: str) -> None:
        self.fd: int | None = None
        if not sys.platform.startswith("linux"):
            return
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            fd = int(libc.inotify_init1(_IN_NONBLOCK))
        except (OSError, AttributeError):
            return
        if fd < 0:
            return
        mask = _IN_OPEN | _IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE
        if int(libc.inotify_add_watch(fd, os.fsencode(device_path), mask)) < 0:
            os.close(fd)
            return
        self.fd = fd

    @property
    def available(self) -> bool:
        """The platform lets this watch see opens (Linux)."""
        return self.fd is not None

    def events(self) -> list[ClientEvent]:
        """The opens and closes since the last call, in order (never blocks; [] when unavailable)."""
        if self.fd is None:
            return []
        out: list[ClientEvent] = []
        while True:
            try:
                data = os.read(self.fd, 4096)
            except (BlockingIOError, InterruptedError):
                return out
            offset = 0
            while offset + _EVENT_HEADER.size <= len(data):
                _, mask, _, name_len = _EVENT_HEADER.unpack_from(data, offset)
                offset += _EVENT_HEADER.size + name_len
                if mask & _IN_OPEN:
                    out.append(ClientEvent.OPENED)
                if mask & (_IN_CLOSE_WRITE | _IN_CLOSE_NOWRITE):
                    out.append(ClientEvent.CLOSED)

    def close(self) -> None:
        """Stop watching."""
        if self.fd is not None:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = None


class PtyPort:
    """A raw pty pair whose slave is symlinked at `link_path`; removes the link on close."""

    @classmethod
    def for_cli(cls, link_path: str) -> PtyPort:
        """`PtyPort(link_path)` for the `--link` option: a path where no link can be made is an InputError."""
        try:
            return cls(link_path)
        except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise InputError(
                f"--link {link_path}: cannot create the link ({reason}); allowed: a new path or an old "
                "symlink in a writable directory"
            ) from None

    def __init__(self, link_path: str | os.PathLike[str]) -> None:
        self.link_path = Path(link_path)
        self.master_fd, self.slave_fd = pty.openpty()
        tty.setraw(self.slave_fd)
        self.slave_name = os.ttyname(self.slave_fd)
        try:
            if self.link_path.is_symlink() or self.link_path.exists():
                if not self.link_path.is_symlink():
                    raise FileExistsError(
                        errno.EEXIST, "exists and is not a symlink; not replacing it", str(self.link_path)
                    )
                self.link_path.unlink()
            self.link_path.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(self.slave_name, self.link_path)
        except BaseException:
            os.close(self.master_fd)
            os.close(self.slave_fd)
            raise
        os.set_blocking(self.master_fd, False)
        self._client_opens: ClientOpens | None = None

    def client_opens(self) -> ClientOpens:
        """The watch on clients opening and closing the slave (made on first use, closed with the link)."""
        if self._client_opens is None:
            self._client_opens = ClientOpens(self.slave_name)
        return self._client_opens

    def client_baud(self) -> int | None:
        """The baud rate the client configured on its side, or None if it is not a standard one."""
        speed = termios.tcgetattr(self.slave_fd)[5]
        return _SPEEDS.get(speed)

    def read(self, max_bytes: int = 65536) -> bytes:
        """Bytes the client wrote, without blocking (b'' when none)."""
        try:
            return os.read(self.master_fd, max_bytes)
        except (BlockingIOError, InterruptedError):
            return b""

    def write(self, data: bytes) -> None:
        """Send bytes to the client, all of them."""
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master_fd, view)
            except BlockingIOError:
                continue
            view = view[n:]

    def close(self) -> None:
        """Remove the symlink (if it is still ours) and close both ends."""
        if self._client_opens is not None:
            self._client_opens.close()
        try:
            if self.link_path.is_symlink() and os.readlink(self.link_path) == self.slave_name:
                self.link_path.unlink()
        finally:
            for fd in (self.master_fd, self.slave_fd):
                with contextlib.suppress(OSError):
                    os.close(fd)

    def __enter__(self) -> PtyPort:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class Stop:
    """A serve loop's flag: it exits once `stopped` is set (by another thread, or a signal)."""

    def __init__(self) -> None:
        self.stopped = False


class StopFlag(Stop):
    """Set by SIGTERM or SIGINT so that a serve loop can exit cleanly and remove its link."""

    def __init__(self) -> None:
        super().__init__()
        signal.signal(signal.SIGTERM, self._stop)
        signal.signal(signal.SIGINT, self._stop)

    def _stop(self, signum: int, frame: FrameType | None) -> None:
        self.stopped = True
