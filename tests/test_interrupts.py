"""The one signal-deferral implementation shared by the servo bus and the runner."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from rig.safety.interrupts import interrupts_deferred, signals_deferred


def test_signals_deferred_remembers_the_signal_and_restores_the_handler():
    before = signal.getsignal(signal.SIGINT)
    with signals_deferred(signal.SIGINT) as received:
        os.kill(os.getpid(), signal.SIGINT)
        assert received == [signal.SIGINT]
    assert signal.getsignal(signal.SIGINT) is before


def test_signals_deferred_is_a_no_op_outside_the_main_thread():
    seen: list[list[int]] = []

    def worker() -> None:
        with signals_deferred(signal.SIGINT) as received:
            seen.append(received)

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert seen == [[]]


def test_interrupts_deferred_raises_only_after_the_block():
    done = []
    with pytest.raises(KeyboardInterrupt), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGTERM)
        done.append(True)
    assert done == [True]


def test_interrupts_deferred_lets_an_exception_of_the_block_through():
    with pytest.raises(ValueError), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        raise ValueError("boom")
