"""`rig setup-servos --rig CONFIG`: give each configured servo its ID and the bus baud, one at a time.

New Dynamixel servos all answer as ID 1 at 57600 baud, so they cannot share a bus until each has
its own ID. This command walks the rig config's servos: for each it asks the operator to connect
that servo alone, finds it at any baud rate (Protocol 2.0), writes the configured ID and the
config's bus baud (torque off; EEPROM), and verifies both at the new rate. It needs a terminal.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence

from rig.cli.commands import COMMANDS
from rig.errors import InputError, RigError
from rig.hw.dxl import control_table as ct
from rig.hw.dxl.setup import assign_id_and_baud, describe_found, find_single_servo, search_order
from rig.inputs.rig_config import ServoSpec
from rig.sim.settings import load_checked_rig_config

DESCRIPTION = """\
Give each servo of the rig config its ID and the bus baud rate, one servo at a time (as a new servo
is ID 1 at 57600 baud, several new ones on one bus answer as one). For each configured servo, in
the config's order: connect that servo alone to the adapter (unplug the others), press Enter; the
servo is found at any baud rate, its torque turned off, its ID and Baud Rate (EEPROM) written and
read back at the new rate. Protocol 2.0 servos only: `rig scan` names a Protocol 1.0 servo and how
to switch it. Needs a terminal (over ssh: `ssh -t`). Not verified on hardware: tested against the
servo emulator (`rig sim servos`).
"""

EPILOG = """\
Exit codes: 0 every servo set and verified; 1 a servo could not be found, written or verified;
2 invalid input (the config, a simulated rig's port, no terminal); 130 interrupted.
"""

Ask = Callable[[str], str]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig setup-servos`."""
    parser = subparsers.add_parser(
        "setup-servos",
        help=COMMANDS["setup-servos"],
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--rig", required=True, help="the rig config whose servos to set up")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Set up every configured servo in turn; see the module docstring."""
    config = load_checked_rig_config(args.rig)
    port = config.servos.port
    if "://" in port:
        raise InputError(
            f"{config.source}: servos.port: {port} is not a serial port; setup-servos talks to real servos "
            "(or to `rig sim servos` through its --link)"
        )
    if not os.path.exists(port):
        raise InputError(f"{config.source}: servos.port: {port}: no such serial port (see `rig ports`)")
    if not sys.stdin.isatty():
        raise InputError(
            "rig setup-servos asks you to connect one servo at a time and waits for Enter: it needs a "
            "terminal on stdin (over ssh use `ssh -t`; not a pipe, a file or a CI job)"
        )
    return setup_all(config.servos.port, config.servos.baud, config.servos.servos, input)


def setup_all(port: str, baud: int, servos: Sequence[ServoSpec], ask: Ask) -> int:
    """Walk the servos, asking before each; 0 when all are set, 1 at the first that cannot be."""
    bauds = search_order(baud)
    for n, spec in enumerate(servos, start=1):
        expected = ct.table_for_model(spec.model)
        prompt = (
            f"[{n}/{len(servos)}] Connect ONLY the {spec.role} servo ({spec.model}, to become id "
            f"{spec.servo_id}) to {port}, with its power on; unplug every other servo. Press Enter "
            "(q then Enter to stop): "
        )
        while True:
            if ask(prompt).strip().lower() == "q":
                print("stopped by the operator; the servos set so far keep their settings")
                return 1
            found = find_single_servo(port, bauds)
            if len(found) == 1 and found[0].model_number == expected.model_number:
                break
            if not found:
                print(
                    "no servo answered at any baud rate (Protocol 2.0): check the servo's power and cable; "
                    "a servo on Protocol 1.0 is found by `rig scan`"
                )
            elif len(found) > 1:
                print(f"{len(found)} servos answered ({describe_found(found)}): connect only one")
            else:
                print(
                    f"found {describe_found(found)}, but the config says {spec.model} "
                    f"({expected.model_number}) for id {spec.servo_id}: connect that servo, or fix the config"
                )
        try:
            done = assign_id_and_baud(port, found[0], spec.servo_id, baud)
        except RigError as exc:
            print(f"servo {spec.servo_id} ({spec.role}): {exc}", file=sys.stderr)
            return 1
        print(
            f"{spec.role} servo {done.model}: id {done.old_id} -> {done.new_id}, baud {done.old_baud} -> "
            f"{done.new_baud} (read back)"
        )
    print(f"all {len(servos)} servo(s) set; connect them together and run `rig scan --port {port}`")
    return 0
