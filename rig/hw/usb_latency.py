"""A USB-serial adapter's latency timer, as Linux shows it in sysfs, and what it costs a control tick.

An FTDI adapter (such as the U2D2) holds a short reply until its latency timer expires; Linux's
`ftdi_sio` driver sets it to 16 ms, and each servo bus transaction then waits up to that long
(Linux `drivers/usb/serial/ftdi_sio.c`; the DynamixelSDK's Linux port handler advises 1 ms).
`docs/udev/99-rig.rules` sets 1 ms at every plug-in. The timer is read from
`<sysfs>/bus/usb-serial/devices/<tty>/latency_timer`; a port without that file (a CDC-ACM board, a
pty, a pyserial URL) has no reading. Not verified on hardware.
"""

from __future__ import annotations

from pathlib import Path

DEFAULT_SYSFS_ROOT = Path("/sys")
# What the udev rule sets; above it, a run says the timer is the likely cause of late ticks.
GOOD_LATENCY_TIMER_MS = 1


def latency_timer_path(sysfs_root: Path, tty_name: str) -> Path:
    """Where Linux shows a USB-serial adapter's latency timer (FTDI `ftdi_sio` ports have one)."""
    return sysfs_root / "bus" / "usb-serial" / "devices" / tty_name / "latency_timer"


def read_latency_timer_ms(port: str, sysfs_root: Path = DEFAULT_SYSFS_ROOT) -> int | None:
    """The latency timer of the adapter behind `port` (a `/dev/serial/by-id/...` link is followed).

    None when the port has none or it cannot be read: a pyserial URL, a port that is not a USB
    serial adapter, an unreadable or non-numeric file.
    """
    if "://" in port:
        return None
    try:
        tty_name = Path(port).resolve().name
        return int(latency_timer_path(sysfs_root, tty_name).read_text().strip())
    except (OSError, ValueError):
        return None


def is_slow(latency_timer_ms: int | None) -> bool:
    """A timer read above `GOOD_LATENCY_TIMER_MS` (no reading is not slow: there is nothing to blame)."""
    return latency_timer_ms is not None and latency_timer_ms > GOOD_LATENCY_TIMER_MS


def latency_timer_cause(latency_timer_ms: int) -> str:
    """What to tell an operator when a slow timer explains late ticks and bus timeouts."""
    return (
        f"the servo port's USB latency timer is {latency_timer_ms} ms (set it to "
        f"{GOOD_LATENCY_TIMER_MS} ms: docs/hardware.md §3, `rig check`)"
    )
