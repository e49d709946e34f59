"""`rig sim rig --rig CONFIG`: serve a config's simulated world behind its own ports until stopped."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path

from rig.errors import InputError
from rig.inputs.files import atomic_write_text
from rig.inputs.protocol import load_protocol
from rig.sim.pty_port import StopFlag
from rig.sim.settings import load_checked_rig_config
from rig.sim.twin import Served, build_twin, serve_twin
from rig.sim.twin_console import HELP, run_console
from rig.sim.twin_firmware import HARNESS_PATH
from rig.sim.twin_ports import PortCondition, TwinDevice

MAX_SEED = 2**32 - 1


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig sim rig`."""
    parser = subparsers.add_parser(
        "rig",
        help="serve a rig config's simulated world behind its own ports (the rig's twin)",
        description=(
            "Serve the world of CONFIG's `simulation:` section (a hardware config may have one; its "
            "runs ignore it) in real time behind the ports the config names: servos.port and "
            "loadcell.port become symlinks to pseudo-terminals (anything there that is not a symlink is "
            "left alone and refused). Every configured servo answers as its own model on one bus; the "
            "load cell sends at the config's baud and format. Then `rig check`, `rig calibrate` and "
            "`rig run` with the unchanged config drive it as they would the rig. With --protocol the "
            "simulated hand sets each trial up (hook distance, bend) while the line is slack. Prints "
            "`SERVOS <link> <pty>` and `LOADCELL <link> <pty>` when ready; `hang KG` and `unhang` "
            "typed on its stdin hang a reference mass in the line (to rehearse `rig calibrate`), `trial N` "
            "sets up trial N (when the run repeats one); `unplug servos|loadcell` pulls that device's "
            "adapter out (the host's open port fails, the link is removed) and `replug` puts it back at "
            "the same path; `freeze servos|loadcell` hangs the adapter (the port stays, nothing passes "
            "either way, the servos' Bus Watchdog trips) and `thaw` frees it; `unplug` and `freeze` take "
            "an optional SECONDS, after which the port is served again; `status` prints the line's "
            "tension, the servos whose torque is on and each port's condition. Runs "
            "until Ctrl-C or SIGTERM (exit 0, links removed). docs/hardware.md, 'Rehearse before the "
            "rig exists'."
        ),
    )
    parser.add_argument("--rig", type=Path, required=True, metavar="CONFIG", help="the rig config (any kind)")
    parser.add_argument(
        "--protocol",
        type=Path,
        default=None,
        metavar="P",
        help="the protocol the run will follow: the hand sets up its trials in turn (default: a "
        "link-validation trial on the straight link, again after each)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="the world's and the protocol's seed: give `rig run` the same (default 0)",
    )
    parser.add_argument(
        "--truth-out",
        type=Path,
        default=None,
        metavar="FILE",
        help="write the world's truth (JSON) here on exit",
    )
    parser.add_argument(
        "--calibration-out",
        type=Path,
        default=None,
        metavar="FILE",
        help="write the calibration that matches the twin's cell here at start (the `rig calibrate` format)",
    )
    parser.add_argument(
        "--firmware",
        type=Path,
        nargs="?",
        const=HARNESS_PATH,
        default=None,
        metavar="HARNESS",
        help="the load cell is the built firmware image under simavr (default harness: firmware/build/"
        "hx711-sim, `make -C firmware all sim`), driven live by the world's tension; needs loadcell.format "
        "rig-lc1 and rate_hz 10, 20, 80 or 320; simulation.loadcell_dtr_reset_s > 0 resets it on every open",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Serve until SIGTERM/SIGINT; returns 0."""
    if not 0 <= args.seed <= MAX_SEED:
        raise InputError(f"--seed {args.seed}: allowed: an integer from 0 to {MAX_SEED}")
    config = load_checked_rig_config(args.rig)
    protocol = None
    if args.protocol is not None:
        protocol = load_protocol(
            args.protocol,
            seed=args.seed,
            joint_count=config.article.joint_count,
            joints_from=config.joints_from,
        )
    twin = build_twin(config, seed=args.seed, protocol=protocol)
    if args.calibration_out is not None:
        _write(args.calibration_out, "--calibration-out", json.dumps(twin.calibration().to_dict(), indent=2))
    stop = StopFlag()

    def ready(servos: Served, loadcell: Served) -> None:
        print(f"SERVOS {servos.link} {servos.device}", flush=True)
        print(f"LOADCELL {loadcell.link} {loadcell.device}{' firmware' if args.firmware else ''}", flush=True)
        if sys.stdin is not None:  # the person at the twin: a daemon thread, it ends with the twin
            console = threading.Thread(
                target=run_console, args=(sys.stdin, twin.reference, sys.stderr, twin.set_up_trial, twin)
            )
            console.daemon = True
            console.start()
            if sys.stdin.isatty():
                print(HELP, file=sys.stderr, flush=True)

    def changed(device: TwinDevice, condition: PortCondition, served: Served | None) -> None:
        where = "" if served is None else f" at {served.link} {served.device}"
        print(f"{device}: {condition}{where}", file=sys.stderr, flush=True)

    try:
        serve_twin(twin, stop, ready=ready, firmware=args.firmware, changed=changed)
    finally:
        if args.truth_out is not None:
            _write(args.truth_out, "--truth-out", json.dumps(twin.truth().to_json(), indent=2))
    print(f"stopped: {len(twin.world.trials)} trials set up, {len(twin.world.slips)} slips", file=sys.stderr)
    return 0


def _write(path: Path, flag: str, text: str) -> None:
    try:
        atomic_write_text(path, text + "\n")
    except OSError as exc:
        raise InputError(f"{flag} {path}: cannot write ({exc.strerror}); allowed: a writable path") from None
