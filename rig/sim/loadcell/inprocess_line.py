"""The in-process transport of the load-cell emulator: a pyserial-like port driven by a `VirtualClock`.

No threads. Each clock advance makes the emulator sample every period up to "now" (so register
the simulated world's `on_advance` listener first, and it has integrated to now when asked for a
tension). Lines then cross a modelled UART at the port's baud rate (8N1), so a read in the middle
of a line returns part of it, exactly as a real port does. Reads never wait and never advance
time: only the clock's owner moves time. Bytes that arrive while the port is closed are lost;
bytes beyond the receive buffer are dropped, like a full kernel tty buffer.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import serial

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.hw.loadcell.calibration import Calibration, indicator_calibration
from rig.hw.loadcell.driver import DEFAULT_BOOT_GRACE_S, SerialLoadCell
from rig.hw.loadcell.formats import MICRONEWTONS_PER_N, IndicatorStCodec, ValueUnitCodec
from rig.sim.loadcell.artefacts import ArtefactModel
from rig.sim.loadcell.emulator import (
    BITS_PER_BYTE,
    DEFAULT_BAUD,
    FaultPlan,
    LoadCellEmulator,
    SignalModel,
    TensionSource,
    firmware_banner,
    wrong_baud_garbage,
)
from rig.sim.settings import SimulatedCell
from rig.sim.virtual_clock import VirtualClock
from rig.vocabulary import LoadCellFormatName

DEFAULT_RX_BUFFER_BYTES = 65536
SIM_PORT = "sim://loadcell"
SIM_CALIBRATION_DATE = "2026-01-01T00:00:00+00:00"


class InProcessLoadCellSerial:
    """A pyserial-compatible port on an emulator: `read`, `readline`, `in_waiting`, `reset_input_buffer`..."""

    def __init__(
        self,
        emulator: LoadCellEmulator,
        clock: VirtualClock,
        *,
        port: str = SIM_PORT,
        baudrate: int | None = None,
        timeout: float | None = 0.0,
        rx_buffer_bytes: int = DEFAULT_RX_BUFFER_BYTES,
        do_not_open: bool = False,
    ) -> None:
        self.emulator = emulator
        self.clock = clock
        self.port = port
        self.baudrate = emulator.baud if baudrate is None else baudrate
        self.timeout = timeout
        self.rx_buffer_bytes = rx_buffer_bytes
        self.is_open = False
        self.bytes_written = 0  # the device ignores host writes; counted for tests
        self.rx_overflow_bytes = 0
        self._byte_ns = BITS_PER_BYTE * 1e9 / emulator.baud
        self._uart_free_ns = float(emulator.start_ns)
        self._tx: deque[tuple[float, bytes]] = deque()  # (transmission start, bytes) per line
        self._rx = bytearray()
        self._last_ns = clock.monotonic_ns()
        clock.on_advance(self._on_advance)
        if not do_not_open:
            self.open()

    # -- device side ------------------------------------------------------------------------------
    def _on_advance(self, now_ns: int) -> None:
        if self._tx:
            self._arrive(now_ns)  # lines already on the wire come first
        tx, byte_ns, free_ns = self._tx, self._byte_ns, self._uart_free_ns
        done: list[bytes] = []  # lines wholly transmitted by now, while none is still on the wire
        for t_sample, data in self.emulator.lines_until(now_ns):
            n_bytes = len(data)
            start = float(t_sample)
            if free_ns > start:  # the UART is still sending earlier bytes
                start = free_ns
            free_ns = start + n_bytes * byte_ns
            # `_arrive`'s test `int(sent) >= n_bytes`, for n_bytes >= 1, without queueing the line.
            if not tx and (now_ns - start) / byte_ns >= n_bytes:
                done.append(data)
            else:
                tx.append((start, data))
        self._uart_free_ns = free_ns
        if done:
            self._receive(b"".join(done))
        if tx:
            self._arrive(now_ns)

    def _arrive(self, now_ns: int) -> None:
        """Move every byte fully transmitted by `now_ns` from the line into the receive buffer."""
        tx, byte_ns = self._tx, self._byte_ns
        done: list[bytes] = []
        while tx:
            start, data = tx[0]
            n_done = int((now_ns - start) / byte_ns)
            if n_done <= 0:
                break
            if n_done >= len(data):
                tx.popleft()
                done.append(data)
            else:
                tx[0] = (start + n_done * byte_ns, data[n_done:])
                done.append(data[:n_done])
                break
        if done:
            self._receive(b"".join(done))

    def _receive(self, data: bytes) -> None:
        """Bytes off the wire into the receive buffer (bytewise: one call per line or per chunk alike)."""
        if not self.is_open:
            return
        if self.baudrate != self.emulator.baud:
            # A receiver at the wrong baud rate sees framing garbage, never the device's lines.
            data = wrong_baud_garbage(data)
        room = self.rx_buffer_bytes - len(self._rx)
        if len(data) > room:
            self.rx_overflow_bytes += len(data) - room
            data = data[:room]
        self._rx += data

    # -- pyserial surface -------------------------------------------------------------------------
    def open(self) -> None:
        """Start receiving (bytes sent while closed were lost); a board with DTR reset restarts."""
        now_ns = self.clock.monotonic_ns()
        self._arrive(now_ns)
        self.emulator.host_opened(now_ns)
        self.is_open = True

    def close(self) -> None:
        """Stop receiving and drop buffered bytes."""
        self.is_open = False
        self._rx.clear()

    @property
    def in_waiting(self) -> int:
        """Bytes received and not yet read (an unplugged device reports one, as the kernel does)."""
        if self.emulator.unplugged:
            return 1
        self._arrive(self.clock.monotonic_ns())
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        """Up to `size` bytes already received; never waits, whatever `timeout` says."""
        if not self.is_open:
            raise OSError(f"{self.port}: port not open")
        if self.emulator.unplugged:  # what pyserial raises when a USB adapter is pulled out
            raise serial.SerialException(
                "device reports readiness to read but returned no data (device disconnected or "
                "multiple access on port?)"
            )
        self._arrive(self.clock.monotonic_ns())
        data = bytes(self._rx[:size])
        del self._rx[:size]
        return data

    def read_all(self) -> bytes:
        """Every byte already received."""
        return self.read(self.in_waiting)

    def readline(self, size: int = -1) -> bytes:
        """Bytes up to and including the next LF if one has been received, else what there is."""
        self._arrive(self.clock.monotonic_ns())
        end = self._rx.find(b"\n")
        n = len(self._rx) if end < 0 else end + 1
        if size >= 0:
            n = min(n, size)
        return self.read(n)

    def reset_input_buffer(self) -> None:
        """Discard received bytes (a line still on the wire keeps arriving, as on a real port)."""
        self._arrive(self.clock.monotonic_ns())
        self._rx.clear()

    def write(self, data: bytes) -> int:
        """Commands to the device (a polled gauge's poll), on the wire at this port's baud rate."""
        self.bytes_written += len(data)
        done_ns = self.clock.monotonic_ns() + round(len(data) * self._byte_ns)
        self.emulator.receive(data, done_ns)
        return len(data)

    def flush(self) -> None:
        """Nothing to flush."""

    def cancel_read(self) -> None:
        """Reads never block, so there is nothing to cancel."""

    def __enter__(self) -> InProcessLoadCellSerial:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def in_process_serial_factory(emulator: LoadCellEmulator, clock: VirtualClock) -> Callable[..., Any]:
    """A `serial_factory` for `SerialLoadCell`: opens (and re-opens) one in-process port on `emulator`."""
    ports: list[InProcessLoadCellSerial] = []

    def factory(
        port: str = SIM_PORT, baudrate: int | None = None, timeout: float | None = 0.0, **_: Any
    ) -> InProcessLoadCellSerial:
        if not ports:
            ser = InProcessLoadCellSerial(emulator, clock, port=port, baudrate=baudrate, timeout=timeout)
            ports.append(ser)
            return ser
        ser = ports[0]  # the device is plugged in once; a re-open uses the same wire
        ser.port, ser.timeout = port, timeout
        ser.baudrate = emulator.baud if baudrate is None else baudrate
        ser.open()
        return ser

    return factory


def simulated_load_cell(
    tension_n: TensionSource,
    clock: VirtualClock,
    *,
    format_name: LoadCellFormatName = LoadCellFormatName.RIG_LC1,
    rate_hz: float = 1000.0,
    calibration: Calibration | None = None,
    signal: SignalModel | None = None,
    faults: FaultPlan | None = None,
    seed: int = 0,
    stale_timeout_s: float = 0.5,
    artefacts: ArtefactModel | None = None,
    baud: int = DEFAULT_BAUD,
    cell: SimulatedCell | None = None,
    clock_error_ppm: float = 0.0,
    dtr_reset_s: float = 0.0,
    boot_grace_s: float = DEFAULT_BOOT_GRACE_S,
) -> tuple[SerialLoadCell, LoadCellEmulator]:
    """The real driver reading an in-process emulator of `tension_n` (not yet opened).

    Without `calibration`, the driver uses the emulator's exact gain and offset, so `force_n`
    tracks `tension_n` up to noise and drift. A `cell` (a profile of `rig.sim.settings.SIMULATED_CELLS`)
    sets the signal model, settling, codec and banner of a cell labs own (`cell_emulator_options`);
    `signal` then only scales its noise (`noise_counts` / the default cell's).
    """
    options: dict[str, Any] = {}
    if cell is not None:
        options = cell_emulator_options(
            cell, noise_scale=(signal or SignalModel()).noise_counts / SignalModel().noise_counts
        )
        signal = options.pop("signal")
    elif format_name == LoadCellFormatName.RIG_LC1:
        options["banner"] = firmware_banner(rate_hz)  # as firmware/rig_hx711 does at boot
    emulator = LoadCellEmulator(
        tension_n,
        format_name=format_name,
        rate_hz=rate_hz,
        baud=baud,
        signal=signal,
        faults=faults,
        seed=seed,
        start_ns=clock.monotonic_ns(),
        artefacts=artefacts,
        clock_error_ppm=clock_error_ppm,
        dtr_reset_s=dtr_reset_s,
        **options,
    )
    if calibration is None:
        calibration = ideal_calibration(emulator)
    driver = SerialLoadCell(
        SIM_PORT,
        baud=emulator.baud,
        format_name=format_name,
        calibration=calibration,
        stale_timeout_s=stale_timeout_s,
        clock=clock,
        serial_factory=in_process_serial_factory(emulator, clock),
        rate_hz=rate_hz if emulator.poll_command is not None or cell is not None else None,
        boot_grace_s=boot_grace_s,
    )
    return driver, emulator


def cell_emulator_options(cell: SimulatedCell, noise_scale: float = 1.0) -> dict[str, Any]:
    """The emulator's signal model, settling, codec and banner for a cell labs own."""
    options: dict[str, Any] = {
        "signal": SignalModel(
            gain_counts_per_n=cell.counts_per_n,
            noise_counts=cell.noise_counts * noise_scale,
            adc_bits=cell.adc_bits,
        ),
        "settling_s": cell.settling_s,
    }
    if cell.format == LoadCellFormatName.VALUE_UNIT:
        options["codec"] = ValueUnitCodec(cell.gauge_unit, cell.gauge_decimals)
    else:
        options["banner"] = firmware_banner(cell.rate_hz)
    return options


def ideal_calibration(emulator: LoadCellEmulator) -> Calibration:
    """The calibration a perfect two-point procedure would find for `emulator` at power-on."""
    codec = emulator.codec
    if isinstance(codec, IndicatorStCodec):
        return indicator_calibration("kg", codec.decimals, serial="sim", date=SIM_CALIBRATION_DATE)
    if isinstance(codec, ValueUnitCodec):  # the gauge reads newtons itself: raw is micronewtons
        return Calibration(
            factor_n_per_count=1.0 / MICRONEWTONS_PER_N,
            offset_counts=0.0,
            reference_mass_kg=None,
            g=STANDARD_GRAVITY_M_S2,
            date=SIM_CALIBRATION_DATE,
            serial="sim",
            format=emulator.format_name,
        )
    signal = emulator.signal
    return Calibration(
        factor_n_per_count=1.0 / signal.gain_counts_per_n,
        offset_counts=signal.offset_counts,
        reference_mass_kg=None,
        g=STANDARD_GRAVITY_M_S2,
        date=SIM_CALIBRATION_DATE,
        serial="sim",
        format=emulator.format_name,
        noise_counts=signal.noise_counts,
    )
