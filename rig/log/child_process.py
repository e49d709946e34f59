"""Starting a helper process of the log layer (MCAP writer, live server) with its two pipes.

Both children are `python -m MODULE REQUEST_FD REPLY_FD [EXTRA_FD ...] ARGS...`: the parent writes
requests into one pipe and reads replies from the other. The child runs in its own process group,
so a terminal's Ctrl-C reaches the run only, which then decides when the child ends (a SIGINT in
the child's first instants, before it ignores the signal, would otherwise kill it).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class ChildProcess:
    """A started child and the parent's ends of its pipes (the caller owns and closes them)."""

    process: subprocess.Popen[bytes]
    request_fd: int  # write end: parent -> child
    reply_fd: int  # read end: child -> parent


def start_child(
    module: str, args: Sequence[str], *, pipe_bytes: int, extra_fds: Sequence[int] = ()
) -> ChildProcess:
    """Start `python -m module` with its request and reply pipes and `extra_fds` handed over.

    The request pipe gets room for `pipe_bytes` where Linux allows. The parent's copies of the
    child's ends, and of `extra_fds`, are closed whether or not the child started.
    """
    try:
        request_read, request_write = os.pipe()
        with contextlib.suppress(AttributeError, OSError):  # F_SETPIPE_SZ: Linux only
            fcntl.fcntl(request_write, fcntl.F_SETPIPE_SZ, pipe_bytes)
        reply_read, reply_write = os.pipe()
        child_fds = (request_read, reply_write, *extra_fds)
        try:
            process = subprocess.Popen(
                [sys.executable, "-m", module, *(str(fd) for fd in child_fds), *args],
                pass_fds=child_fds,
                stdin=subprocess.DEVNULL,
                close_fds=True,
                process_group=0,
            )
        except BaseException:
            for fd in (request_write, reply_read):
                os.close(fd)
            raise
        finally:
            for fd in (request_read, reply_write):
                os.close(fd)
    finally:
        for fd in extra_fds:
            os.close(fd)
    return ChildProcess(process, request_write, reply_read)
