"""Interlock checks and the deferred-interrupt guard around the safe-state sequence."""

from __future__ import annotations

import os
import signal

import pytest

from rig.hw.seams import ServoState
from rig.safety.interlocks import CurrentAtLimit, ForceCeiling, ServoHealth
from rig.safety.interrupts import interrupts_deferred


def state(current_a: float = 0.0, hardware_error: int = 0) -> ServoState:
    return ServoState(1, 0.0, 0.0, current_a, hardware_error, False, 0)


def test_force_ceiling_names_value_and_limit():
    assert ForceCeiling(10.0).check(9.99) is None
    reason = ForceCeiling(10.0).check(10.5)
    assert "10.50 N" in reason and "10.00 N" in reason


def test_servo_health_decodes_the_error_bits():
    health = ServoHealth({1: "winch"})
    assert health.check({1: state()}) is None
    reason = health.check({1: state(hardware_error=0x20)})
    assert "servo 1 (winch)" in reason and "overload" in reason


def test_current_at_limit_trips_only_when_held():
    check = CurrentAtLimit(winch_id=1, limit_a=1.0, hold_s=1.0)
    assert check.check({1: state(0.99)}, 0) is None
    assert check.check({1: state(0.99)}, 900_000_000) is None
    assert check.check({1: state(0.5)}, 950_000_000) is None  # dropped: the timer restarts
    assert check.check({1: state(-0.99)}, 1_000_000_000) is None
    reason = check.check({1: state(-0.99)}, 2_000_000_000)
    assert reason is not None and "1.00 s" in reason and "0.990 A" in reason


def _operator_handler(signum, frame):
    raise AssertionError("the handler installed before the deferral ran inside it")


def _terminate_handler(signum, frame):
    raise AssertionError("the SIGTERM handler installed before the deferral ran inside it")


@pytest.mark.parametrize(
    "sigint_before",
    ["as found", signal.default_int_handler, signal.SIG_IGN, _operator_handler],
    ids=["as-found", "python-default", "ignored", "custom"],
)
def test_a_second_ctrl_c_cannot_interrupt_the_safe_state_sequence(signal_handlers, sigint_before):
    # The deferral must put back exactly the handlers it found, not Python's defaults: a process
    # started with SIGINT ignored (nohup, a background job) must stay that way after a safe stop.
    if sigint_before == "as found":
        sigint_before = signal.getsignal(signal.SIGINT)
    else:
        signal.signal(signal.SIGINT, sigint_before)
    signal.signal(signal.SIGTERM, _terminate_handler)
    steps = []
    with pytest.raises(KeyboardInterrupt), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        steps.append("released")
        os.kill(os.getpid(), signal.SIGTERM)
        steps.append("torque off")
    assert steps == ["released", "torque off"]
    assert signal.getsignal(signal.SIGINT) is sigint_before
    assert signal.getsignal(signal.SIGTERM) is _terminate_handler
