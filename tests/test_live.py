"""The live view: a simulated run served over the Foxglove WebSocket protocol, checked against its MCAP."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import signal
import socket
import struct
import threading
import time
from pathlib import Path

import jsonschema
import pytest
import websockets
from mcap.reader import make_reader

from rig.errors import InputError
from rig.log.format import schemas
from rig.log.live.publisher import LivePublisher, serve_log
from rig.rigs import open_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.runner.sinks import LiveSink
from tests.helpers import QUICK_PROTOCOL, quick_protocol

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]  # foxglove-sdk speaks the first
WATCHED = (schemas.LOADCELL, schemas.SLIP, schemas.ESTIMATE)
MESSAGE_DATA = 0x01
TIME = 0x02
ONE_TRIAL = quick_protocol(block={"distances_m": [0.2]})


class FoxgloveClient:
    """A minimal Foxglove WebSocket client in a thread: subscribes to topics, keeps what arrives."""

    def __init__(self, url: str, topics: tuple[str, ...]) -> None:
        self.url, self.topics = url, topics
        self.channels: dict[int, dict] = {}  # channel id -> advertised channel
        self.received: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
        self.times: list[int] = []  # server time messages (playback of a recorded log)
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, daemon=True)
        self._thread.start()

    def join(self, timeout_s: float = 30.0) -> None:
        self._thread.join(timeout_s)
        assert not self._thread.is_alive()
        if self.error is not None:
            raise self.error

    def _main(self) -> None:
        try:
            asyncio.run(self._session())
        except BaseException as error:
            self.error = error

    async def _session(self) -> None:
        async with websockets.connect(self.url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
            assert ws.subprotocol in SUBPROTOCOLS
            subscription_topic: dict[int, str] = {}
            try:
                async for frame in ws:
                    if isinstance(frame, str):
                        message = json.loads(frame)
                        if message["op"] == "advertise":
                            self.channels.update({c["id"]: c for c in message["channels"]})
                            wanted = [c for c in message["channels"] if c["topic"] in self.topics]
                            subs = []
                            for channel in wanted:
                                sub_id = len(subscription_topic) + 1
                                subscription_topic[sub_id] = channel["topic"]
                                subs.append({"id": sub_id, "channelId": channel["id"]})
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        continue
                    if frame[0] == TIME:
                        self.times.append(struct.unpack_from("<Q", frame, 1)[0])
                        continue
                    assert frame[0] == MESSAGE_DATA
                    sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                    self.received[subscription_topic[sub_id]].append((log_time, bytes(frame[13:])))
            except websockets.ConnectionClosed:
                pass


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def file_messages(path: Path) -> dict[str, list[tuple[int, object]]]:
    out: dict[str, list[tuple[int, object]]] = {}
    with path.open("rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    return out


@pytest.mark.slow  # a few seconds: the in-process client competes with the run for the GIL
def test_a_live_run_serves_the_logged_topics_with_their_schemas(tmp_path, protocol_file):
    protocol = protocol_file(ONE_TRIAL)
    prepared = prepare_run(RunRequest(protocol_path=protocol, rig_path=None, out_dir=tmp_path, seed=3))
    with LivePublisher(port=0) as live:
        assert live.wait_ready()  # the server process listens
        client = FoxgloveClient(live.url, WATCHED)
        deadline = time.monotonic() + 10
        while not all(live.wants(t) for t in WATCHED):
            assert time.monotonic() < deadline, "the client did not subscribe"
            time.sleep(0.01)
        report = execute_run(prepared, open_rig(prepared), SilentProgress(), LiveSink(live))
        stats = live.close()
    client.join()
    assert report.exit_code == 0, report.reason

    advertised = {c["topic"]: c for c in client.channels.values()}
    assert set(advertised) == set(schemas.TOPICS)
    for topic, spec in schemas.TOPICS.items():
        assert advertised[topic]["schemaName"] == spec.schema_name
        assert advertised[topic]["schemaEncoding"] == "jsonschema"
        assert advertised[topic]["encoding"] == "json"
        assert json.loads(advertised[topic]["schema"]) == spec.schema

    logged = file_messages(prepared.log_path)
    for topic in WATCHED:
        received = client.received[topic]
        assert received, f"nothing received on {topic}"
        schema = json.loads(advertised[topic]["schema"])
        in_file = {(t, json.dumps(p, sort_keys=True)) for t, p in logged[topic]}
        for log_time, data in received:
            payload = json.loads(data)
            jsonschema.validate(payload, schema)
            assert (log_time, json.dumps(payload, sort_keys=True)) in in_file, (topic, payload)
    # Few and far between: nothing of these may be lost.
    assert len(client.received[schemas.ESTIMATE]) == len(logged[schemas.ESTIMATE])
    assert len(client.received[schemas.SLIP]) == len(logged[schemas.SLIP])
    assert stats.published >= sum(len(client.received[t]) for t in WATCHED)
    # The run's log ends with the live view's counts.
    assert "live view:" in logged[schemas.LOG][-1][1]["message"]


def test_unsubscribed_topics_cost_nothing_and_are_not_queued():
    with LivePublisher(port=0) as live:
        assert live.wait_ready()  # the server process listens
        assert not live.wants(schemas.LOADCELL)
        live.publish(schemas.LOADCELL, [(1, (1, 2, 0.5, 3))])  # the logger checks wants() first
        stats = live.close()
    assert stats.dropped == 0


def test_the_server_process_has_its_own_process_group_so_a_terminal_ctrl_c_reaches_only_the_run():
    # The terminal sends SIGINT to its foreground group; the run then closes the view in order.
    with LivePublisher(port=0) as live:
        assert os.getpgid(live.pid) == live.pid != os.getpgid(0)
        live.close()


def test_a_server_process_that_falls_behind_loses_batches_counted_and_publishing_never_waits():
    with LivePublisher(port=0, pipe_bytes=4096, client_backlog=1 << 20) as live:
        assert live.wait_ready()  # the server process listens
        client = FoxgloveClient(live.url, (schemas.LOADCELL,))
        wait_until_subscribed(live, (schemas.LOADCELL,))
        os.kill(live.pid, signal.SIGSTOP)  # the server process stops reading its pipe
        try:
            publishing = threading.Thread(
                target=lambda: [
                    live.publish(schemas.LOADCELL, [(i * 1000 + j, (j, 1, 0.5, j)) for j in range(100)])
                    for i in range(200)
                ]
            )
            publishing.start()
            publishing.join(30)  # were publish() to wait for the stopped process, it would never end
            assert not publishing.is_alive()
            assert live.stats().dropped > 0
        finally:
            os.kill(live.pid, signal.SIGCONT)
        stats = live.close()
    client.join()
    assert stats.dropped > 0 and stats.published > 0
    assert stats.published + stats.dropped == 20_000
    assert len(client.received[schemas.LOADCELL]) <= stats.published


def test_a_port_in_use_is_an_input_error():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=f"--live-port {port}"):
            LivePublisher(port=port)


def test_a_port_taken_after_the_check_is_reported_by_the_view_not_hung_on(monkeypatch):
    import rig.log.live.publisher as live_module

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        monkeypatch.setattr(live_module, "_free_port", lambda host, port_: port)  # lost the race
        live = LivePublisher(port=0)
        assert not live.wait_ready(10)
        live.publish(schemas.LOG, [(1, {})])  # ignored: nobody can subscribe
        stats = live.close()
    assert stats.failure is not None and str(port) in stats.failure
    assert stats.text().startswith("live view: not served")


def test_rig_run_live_on_a_port_in_use_exits_2_before_anything_is_written(tmp_path, protocol_file, run_cli):
    protocol = protocol_file(QUICK_PROTOCOL)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = run_cli(
            "run", str(protocol), "--out", str(tmp_path / "out"), "--live", "--live-port", str(port)
        )
    assert result.code == 2
    assert f"--live-port {port}" in result.err
    assert len(result.err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def wait_until_subscribed(live: LivePublisher, topics: tuple[str, ...]) -> None:
    deadline = time.monotonic() + 10
    while not all(live.wants(t) for t in topics):
        assert time.monotonic() < deadline, "the client did not subscribe"
        time.sleep(0.01)


@pytest.mark.slow  # a simulated run, then its replay
def test_replay_serve_streams_a_recorded_log_in_log_time_order(tmp_path, protocol_file):
    protocol = protocol_file(ONE_TRIAL)
    prepared = prepare_run(RunRequest(protocol_path=protocol, rig_path=None, out_dir=tmp_path, seed=5))
    assert execute_run(prepared, open_rig(prepared), SilentProgress()).exit_code == 0
    logged = file_messages(prepared.log_path)
    with LivePublisher(port=0, client_backlog=1 << 20, playback=True) as live:
        assert live.wait_ready()  # the server process listens
        client = FoxgloveClient(live.url, WATCHED)
        sent, warnings = serve_log(
            [prepared.log_path],
            live,
            speed=50.0,
            wait_for_client=lambda: wait_until_subscribed(live, WATCHED),
        )
        live.close()
    client.join()
    assert warnings == []
    assert client.times == sorted(client.times) and client.times
    assert sent == sum(len(v) for t, v in logged.items() if t in schemas.TOPICS)
    for topic in WATCHED:
        expected = sorted((t, json.dumps(p, sort_keys=True)) for t, p in logged[topic])
        got = [(t, json.dumps(json.loads(d), sort_keys=True)) for t, d in client.received[topic]]
        assert [t for t, _ in got] == sorted(t for t, _ in got), f"{topic}: not in log-time order"
        assert sorted(got) == expected, topic


def test_replay_serve_refuses_a_bad_speed(tmp_path, run_cli):
    log = tmp_path / "x.mcap"
    log.write_bytes(b"")
    result = run_cli("replay", str(log), "--serve", "--speed", "0")
    assert result.code == 2 and "--speed" in result.err


def test_serve_log_paces_messages_by_log_time(tmp_path, protocol_file):
    clock = [0.0]
    slept: list[float] = []

    def sleep(s: float) -> None:
        slept.append(s)
        clock[0] += s

    protocol = protocol_file(ONE_TRIAL)
    prepared = prepare_run(RunRequest(protocol_path=protocol, rig_path=None, out_dir=tmp_path, seed=5))
    assert execute_run(prepared, open_rig(prepared), SilentProgress()).exit_code == 0
    times = sorted(t for v in file_messages(prepared.log_path).values() for t, _ in v)
    with LivePublisher(port=0, playback=True) as live:
        serve_log([prepared.log_path], live, speed=2.0, sleep=sleep, monotonic=lambda: clock[0])
    assert clock[0] == pytest.approx((times[-1] - times[0]) / 1e9 / 2.0, abs=0.002)


def stalled_client(port: int) -> socket.socket:
    """A client that subscribes to every channel, then never reads (a tiny receive window)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        "GET / HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n".encode()
    )
    data = b""
    while b"\r\n\r\n" not in data:
        data += sock.recv(4096)
    assert data.startswith(b"HTTP/1.1 101")
    data = data.split(b"\r\n\r\n", 1)[1]
    channels: list[int] = []
    while not channels:  # server frames are unmasked: serverInfo, then advertise
        while len(data) < 4:
            data += sock.recv(65536)
        length, start = data[1] & 0x7F, 2
        if length == 126:
            length, start = int.from_bytes(data[2:4], "big"), 4
        elif length == 127:
            length, start = int.from_bytes(data[2:10], "big"), 10
        while len(data) < start + length:
            data += sock.recv(65536)
        message = json.loads(data[start : start + length])
        data = data[start + length :]
        if message["op"] == "advertise":
            channels = [c["id"] for c in message["channels"]]
    subs = [{"id": i, "channelId": c} for i, c in enumerate(channels, 1)]
    payload = json.dumps({"op": "subscribe", "subscriptions": subs}).encode()
    mask = os.urandom(4)
    header = bytes([0x81, 0x80 | 126]) + len(payload).to_bytes(2, "big") + mask
    sock.sendall(header + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))
    return sock


@pytest.mark.slow  # a few seconds: enough data to fill the kernel's socket buffers too
def test_a_stalled_client_loses_messages_counted_and_neither_publishing_nor_closing_waits():
    with LivePublisher(port=0, client_backlog=16) as live:
        assert live.wait_ready()  # the server process listens
        sock = stalled_client(live.port)
        wait_until_subscribed(live, (schemas.LOADCELL,))
        start = time.perf_counter()
        for i in range(600):
            live.publish(schemas.LOADCELL, [(i * 1000 + j, (j, 1, 0.5, j)) for j in range(100)])
        assert time.perf_counter() - start < 1.0
        start = time.perf_counter()
        stats = live.close(timeout_s=1.0)  # the server's stop waits for the stalled client: not we
        assert time.perf_counter() - start < 5.0
        sock.close()
    assert stats.published + stats.dropped == 60_000
    assert stats.slow_client_events >= 1


def test_the_foxglove_layout_names_only_logged_topics_and_fields():
    layout = json.loads((Path(__file__).parent.parent / "docs" / "foxglove-layout.json").read_text())
    panels = layout["configById"]
    paths = [p["value"] for config in panels.values() for p in config.get("paths", [])]
    paths += [config["xAxisPath"]["value"] for config in panels.values() if "xAxisPath" in config]
    paths += [
        config[key] for config in panels.values() for key in ("topicPath", "topicToRender") if key in config
    ]
    paths += [topic for config in panels.values() for topic in config.get("topics", {})]
    assert paths
    for path in paths:
        topic = next(t for t in sorted(schemas.TOPICS, key=len, reverse=True) if path.startswith(t))
        rest = path[len(topic) :]
        if rest.startswith("{"):
            condition = rest[1 : rest.index("}")]
            flag = condition.split("==")[0]
            assert flag in schemas.TOPICS[topic].schema["properties"], path
            rest = rest[rest.index("}") + 1 :]
        if rest:
            field = rest.lstrip(".").split("[")[0]
            assert field in schemas.TOPICS[topic].schema["properties"], path
    # A custom x-axis pairs x and y values by position: every series must come from the same messages,
    # those a boolean flag on the topic marks as carrying every plotted field.
    for config in panels.values():
        if config.get("xAxisVal") == "custom":
            x_path = config["xAxisPath"]["value"]
            message_filter = x_path[: x_path.index("}") + 1]
            flag = message_filter.split("{")[1].split("==")[0]
            topic = message_filter.split("{")[0]
            assert schemas.TOPICS[topic].schema["properties"][flag]["type"] == "boolean"
            assert all(p["value"].startswith(message_filter + ".") for p in config["paths"]), config
    # every panel is placed in the layout tree
    text = json.dumps(layout["layout"])
    assert all(f'"{panel}"' in text for panel in panels)


@pytest.mark.parametrize(
    "row",
    [(1, 120268, 0.00335, 2000), (2, -5, None, 3), (3, 0, -0.0, 4), (4, 1, 1.5e-7, 5), (5, 1, 1e300, 6)],
)
def test_a_load_cell_row_is_published_as_the_object_the_file_holds(row):
    from rig.log.format.encoding import row_encoder
    from rig.log.live.server_process import _DUMPS

    fields = schemas.ROW_FIELDS[schemas.LOADCELL]
    assert json.loads(row_encoder(fields, _DUMPS)(row)) == schemas.row_payload(schemas.LOADCELL, row)


def test_rig_run_live_prints_the_address_and_logs_the_counts(tmp_path, protocol_file, run_cli):
    protocol = protocol_file(ONE_TRIAL)
    out = tmp_path / "out"
    result = run_cli("run", protocol, "--out", out, "--run-id", "l1", "--live", "--live-port", "0")
    assert result.code == 0, result.err
    assert "live view: ws://127.0.0.1:" in result.err
    last = file_messages(out / "l1.mcap")[schemas.LOG][-1][1]
    assert last["message"].startswith("live view: 0 messages published, 0 dropped")
