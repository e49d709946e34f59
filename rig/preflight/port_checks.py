"""Pre-flight section `ports`: each serial port present, readable and writable, and its USB latency timer.

Nothing is opened here. A port is a path (a `/dev/serial/by-id/...` link is followed to its
`ttyUSB*`/`ttyACM*`); a pyserial URL or the simulator's `sim://` ports have nothing to check. The
latency timer of a USB-serial adapter that has one (FTDI, such as the U2D2) is read from
`<sysfs>/bus/usb-serial/devices/<tty>/latency_timer`: Linux's default of 16 ms costs most of a 20 ms
control tick per bus transaction (notes from the Linux `ftdi_sio` driver and the DynamixelSDK);
`docs/udev/99-rig.rules` sets it to 1 ms at every plug-in. Not verified on hardware.
"""

from __future__ import annotations

import grp
import os
import stat
from collections.abc import Callable
from pathlib import Path

from rig.hw.usb_latency import latency_timer_path
from rig.preflight.check_context import CheckContext
from rig.preflight.verdicts import CheckRow, Verdict

SECTION = "ports"
UDEV_RULE = "docs/udev/99-rig.rules"
INSTALL_RULE = (
    f"sudo cp {UDEV_RULE} /etc/udev/rules.d/ && sudo udevadm control --reload-rules && "
    "sudo udevadm trigger (or unplug and replug the adapter)"
)
# The latency timer a control tick of 20 ms can live with (1 ms is what the udev rule sets).
LATENCY_OK_MS = 2
LATENCY_FAIL_MS = 8


def port_rows(ctx: CheckContext) -> list[CheckRow]:
    """Rows for the servo bus's and the load cell's ports."""
    config = ctx.config
    rows: list[CheckRow] = []
    for label, port in (("servo bus", config.servos.port), ("load cell", config.loadcell.port)):
        rows += check_port(label, port, ctx.options.sysfs_root)
    return rows


def check_port(
    label: str,
    port: str,
    sysfs_root: Path,
    *,
    access: Callable[[str, int], bool] = os.access,
    effective_uid: Callable[[], int] = os.geteuid,
) -> list[CheckRow]:
    """Presence and permission of one port, then its latency timer where it has one."""
    if "://" in port:
        return [
            CheckRow(SECTION, f"{label} port", Verdict.PASS, f"{port}: not a device file (nothing to check)")
        ]
    path = Path(port)
    if not path.exists():
        fix = (
            "plug the adapter in; `rig ports` lists the ports present. Name it by "
            "/dev/serial/by-id/... in the rig config, so that two adapters cannot swap names on a reboot"
        )
        return [CheckRow(SECTION, f"{label} port", Verdict.FAIL, f"{port}: no such device", fix)]
    real = path.resolve()
    shown = port if str(real) == port else f"{port} -> {real}"
    rows = [_permission_row(label, shown, real, access, effective_uid)]
    if not port.startswith("/dev/serial/by-"):
        rows.append(
            CheckRow(
                SECTION,
                f"{label} port name",
                Verdict.WARN if real.name.startswith(("ttyUSB", "ttyACM")) else Verdict.PASS,
                port,
                "two USB adapters can swap ttyUSB/ttyACM numbers on a reboot: use the port's "
                "/dev/serial/by-id/... name (`ls -l /dev/serial/by-id/`)"
                if real.name.startswith(("ttyUSB", "ttyACM"))
                else "",
            )
        )
    rows.append(latency_row(label, real.name, sysfs_root))
    return rows


def _permission_row(
    label: str,
    shown: str,
    real: Path,
    access: Callable[[str, int], bool],
    effective_uid: Callable[[], int],
) -> CheckRow:
    check = f"{label} port permission"
    if access(str(real), os.R_OK | os.W_OK):
        return CheckRow(SECTION, check, Verdict.PASS, f"{shown}: readable and writable")
    info = real.stat()
    try:
        group = grp.getgrgid(info.st_gid).gr_name
    except KeyError:
        group = str(info.st_gid)
    mode = stat.filemode(info.st_mode)
    fix = (
        f"add yourself to group {group}: `sudo usermod -aG {group} $USER`, then log out and in again "
        f"(or install the udev rule, which makes the adapter's port {group}-writable: {INSTALL_RULE})"
    )
    return CheckRow(
        SECTION,
        check,
        Verdict.FAIL,
        f"{shown}: {mode}, group {group}; uid {effective_uid()} cannot open it",
        fix,
    )


def latency_row(label: str, tty_name: str, sysfs_root: Path) -> CheckRow:
    """The adapter's latency timer: pass at <= 2 ms, warn up to 8 ms, fail beyond (16 ms by default)."""
    check = f"{label} USB latency timer"
    path = latency_timer_path(sysfs_root, tty_name)
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        return CheckRow(SECTION, check, Verdict.PASS, f"{tty_name}: no latency timer (not an FTDI adapter)")
    except OSError as exc:
        return CheckRow(SECTION, check, Verdict.WARN, f"{path}: unreadable ({exc.strerror})", INSTALL_RULE)
    try:
        latency_ms = int(text)
    except ValueError:
        return CheckRow(SECTION, check, Verdict.WARN, f"{path}: {text!r} is not a number", INSTALL_RULE)
    measured = f"{latency_ms} ms ({path})"
    if latency_ms <= LATENCY_OK_MS:
        return CheckRow(SECTION, check, Verdict.PASS, measured)
    fix = (
        f"install the shipped udev rule, which sets 1 ms at every plug-in: {INSTALL_RULE}; "
        f"for this session only: `echo 1 | sudo tee {path}`"
    )
    verdict = Verdict.WARN if latency_ms <= LATENCY_FAIL_MS else Verdict.FAIL
    return CheckRow(SECTION, check, verdict, measured + "; each bus transaction waits for it", fix)
