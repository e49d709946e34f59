"""A Ctrl-C while `rig` imports its commands ends it with 130, even where importlib would swallow it.

CPython prints and ignores an exception raised in a weakref callback, and importlib's module-lock
cleanup is one: a SIGINT that lands there was lost, and `rig run --realtime` ran on for minutes
(seen once in the README's test command, `test_a_signal_early_in_rig_run_exits_130...[0.1-SIGINT]`).
Here the swallowing is made certain: the signal arrives inside a block that ignores every exception,
as that callback does. The command must still end interrupted, once the imports are done.
"""

from __future__ import annotations

import os
import signal

import rig.cli
from rig.errors import ExitCode


def test_a_ctrl_c_swallowed_during_the_imports_still_ends_the_command(monkeypatch, capsys):
    build = rig.cli.build_parser

    def build_with_a_swallowed_interrupt(argv):  # type: ignore[no-untyped-def]
        try:  # what a weakref callback does with an exception: print it, go on
            os.kill(os.getpid(), signal.SIGINT)
            signal.pthread_sigmask(signal.SIG_BLOCK, [])  # a point where Python runs the handler
        except BaseException:
            pass
        return build(argv)

    monkeypatch.setattr(rig.cli, "build_parser", build_with_a_swallowed_interrupt)
    assert rig.cli.main(["--version"]) == ExitCode.INTERRUPTED
    assert "rig: interrupted" in capsys.readouterr().err
