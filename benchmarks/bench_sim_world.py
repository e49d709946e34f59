"""Cost of the simulated world per substep, alone and coupled to an emulated winch servo.

Work: 60 s of virtual time of a link-validation trial with the winch reeling in steadily (stick-slip
the whole time), in 1 ms substeps, advanced in 10 ms clock steps as a runner polling at 100 Hz would.

* `world + scripted shaft`: the world's own cost (a test-double shaft turning at a constant rate).
* `world + emulated XM430 (mode 5)`: the world stepping a real `rig.sim.dxl.servo.Servo` each substep.
* baseline `emulated XM430 alone`: the same servo advanced through the same substeps with a constant
  external torque and no world: the plain emulator doing the servo's share of the work.

Printed: wall time, real-time factor (virtual s / wall s), µs per substep, slips, and the ratio of
the coupled run to the servo-alone baseline (the world's overhead on top of the emulator).

    .venv/bin/python benchmarks/bench_sim_world.py [--seconds 60] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.hw.dxl import control_table as ct
from rig.sim.dxl.servo import Servo
from rig.sim.physics.link_presets import make_preset
from rig.sim.physics.world import SimWorld

MS = 1_000_000
CLOCK_STEP_NS = 10 * MS


class ScriptedShaft:
    def __init__(self) -> None:
        self.present_position_rad = 0.0
        self.external_torque_nm = 0.0


def winch_servo() -> Servo:
    servo = Servo(ct.table_for_model("XM430-W350"), 1)

    def write(address: int, value: int, size: int) -> None:
        assert servo.write(address, value.to_bytes(size, "little", signed=True), 0).error == 0

    write(ct.ADDR_OPERATING_MODE, 5, 1)
    write(112, round(0.2 / ct.RAD_S_PER_VELOCITY_UNIT), 4)  # Profile Velocity 0.2 rad/s
    write(ct.ADDR_GOAL_CURRENT, round(1.5 / ct.CURRENT_UNIT_A), 2)
    write(ct.ADDR_TORQUE_ENABLE, 1, 1)
    write(ct.ADDR_GOAL_POSITION, round(100.0 / ct.RAD_PER_PULSE), 4)
    return servo


def run_world(seconds: float, use_servo: bool) -> tuple[float, int]:
    preset = make_preset("link1", seed=0)
    if use_servo:
        servo = winch_servo()
        world = SimWorld(preset, servo, step_devices=servo.advance_to)
    else:
        shaft = ScriptedShaft()

        def ramp(t_ns: int) -> None:
            shaft.present_position_rad = 0.2 * t_ns * 1e-9

        world = SimWorld(preset, shaft, step_devices=ramp)
    world.set_configuration([0.2, -0.1, 0.0, 0.1, 0.0, 0.1, -0.1, 0.0])
    world.hook_link()
    end_ns = round(seconds * 1e9)
    t0 = time.perf_counter()
    for t in range(CLOCK_STEP_NS, end_ns + 1, CLOCK_STEP_NS):
        world.advance_to(t)
    return time.perf_counter() - t0, len(world.slips)


def run_servo_alone(seconds: float) -> float:
    servo = winch_servo()
    servo.external_torque_nm = -0.05
    end_ns = round(seconds * 1e9)
    t0 = time.perf_counter()
    for t in range(MS, end_ns + 1, MS):
        servo.advance_to(t)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="virtual seconds per run")
    parser.add_argument("--repeats", type=int, default=3, help="best of N")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # long enough for the stick-slip to slip
        args.seconds, args.repeats = 5.0, 1
    substeps = round(args.seconds * 1000)
    rows = []
    scripted = min(run_world(args.seconds, False) for _ in range(args.repeats))
    coupled = min(run_world(args.seconds, True) for _ in range(args.repeats))
    alone = min(run_servo_alone(args.seconds) for _ in range(args.repeats))
    rows.append(("world + scripted shaft", scripted[0], scripted[1]))
    rows.append(("world + emulated XM430 (mode 5)", coupled[0], coupled[1]))
    rows.append(("emulated XM430 alone (baseline)", alone, None))
    print(f"{args.seconds:g} s virtual, {substeps} substeps of 1 ms, best of {args.repeats}")
    for name, wall, slips in rows:
        print(
            f"  {name:34s} {wall:7.3f} s wall  {args.seconds / wall:8.0f}x real time  "
            f"{wall / substeps * 1e6:6.2f} us/substep" + (f"  {slips} slips" if slips is not None else "")
        )
    print(f"  ratio coupled / servo alone: {coupled[0] / alone:.2f}")
    if args.smoke and not (scripted[1] and coupled[1]):
        raise SystemExit("smoke: the line never slipped")


if __name__ == "__main__":
    main()
