"""JSON payloads to columns: batches of one topic's messages become Arrow tables, then a DataFrame.

Payloads are decoded a batch at a time (joined with newlines and parsed by `pyarrow.json`), never
one dict per message, so memory stays near the size of the columns. Fields of rig topics get the
Arrow types their JSON Schema implies (so a column keeps its dtype even when a batch has only
nulls); fields nobody declared are inferred. A batch that pyarrow cannot parse is decoded row by
row with `json.loads` instead, and rows that are not JSON objects are dropped with a warning.

Bounds, for damaged or hostile logs: a batch is decoded once it holds `DEFAULT_BATCH_SIZE` payloads
or `MAX_PENDING_BYTES` of them, and a payload nested deeper than `MAX_JSON_DEPTH` is dropped with a
warning before pyarrow sees it (pyarrow's JSON reader overflows the stack, a segfault, on deep
enough nesting).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.json as pa_json

from rig.log.format import schemas

DEFAULT_BATCH_SIZE = 100_000
MAX_PENDING_BYTES = 64 << 20
MAX_JSON_DEPTH = 64  # rig payloads nest 5 deep at most
TIME_COLUMNS = ("log_time_ns", "publish_time_ns")
# Nesting level change per byte: +1 for `{` and `[`, -1 for `}` and `]` (in strings too: an overestimate).
_DEPTH_STEP = np.zeros(256, np.int8)
_DEPTH_STEP[[ord("{"), ord("[")]] = 1
_DEPTH_STEP[[ord("}"), ord("]")]] = -1
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"{}[]\n")
_DEPTH_BLOCK = 1 << 18


def _arrow_type(schema: Mapping[str, Any]) -> pa.DataType | None:
    """The Arrow type a JSON Schema fragment implies, or None to let pyarrow infer it."""
    if "oneOf" in schema and all(isinstance(alt.get("const"), int) for alt in schema["oneOf"]):
        return pa.int64()
    types = {t for t in schemas.json_types(schema) if t != "null"}
    if len(types) != 1:
        return None
    (kind,) = types
    if kind == "integer":
        return pa.int64()
    if kind == "number":
        return pa.float64()
    if kind == "string":
        return pa.string()
    if kind == "boolean":
        return pa.bool_()
    if kind == "array":
        item = _arrow_type(schema.get("items", {}))
        return None if item is None else pa.list_(item)
    if kind == "object" and schema.get("additionalProperties", True) is False and schema.get("properties"):
        fields = [(name, _arrow_type(sub)) for name, sub in schema["properties"].items()]
        if any(t is None for _, t in fields):
            return None
        return pa.struct(fields)
    if kind == "object" and schema.get("title") == "time":
        return pa.struct([("sec", pa.int64()), ("nsec", pa.int64())])
    return None


def arrow_schema(topic: str) -> pa.Schema | None:
    """Explicit Arrow types for the declared fields of a rig topic (None for other topics)."""
    spec = schemas.TOPICS.get(topic)
    if spec is None:
        return None
    fields = []
    for name, sub in spec.schema["properties"].items():
        arrow_type = _arrow_type(sub)
        if arrow_type is not None:
            fields.append(pa.field(name, arrow_type))
    return pa.schema(fields)


class TopicBatches:
    """One topic's messages: raw payloads pending decode, and the Arrow tables decoded so far.

    The reader appends to `payloads`, `log_times` and `publish_times` directly (hot loop), adds an
    upper bound of the bytes it appended to `pending_bytes`, and calls `decode_pending()` once
    `len(payloads)` reaches the batch size or `pending_bytes` reaches `max_pending_bytes`.
    """

    def __init__(
        self, topic: str, batch_size: int = DEFAULT_BATCH_SIZE, max_pending_bytes: int = MAX_PENDING_BYTES
    ) -> None:
        self.topic = topic
        self.batch_size = batch_size
        self.max_pending_bytes = max_pending_bytes
        self.pending_bytes = 0
        self.payloads: list[bytes] = []
        self.log_times: list[int] = []
        self.publish_times: list[int] = []
        self.tables: list[pa.Table] = []
        self.warnings: list[str] = []
        self._explicit = arrow_schema(topic)

    def decode_pending(self) -> None:
        """Decode the pending payloads into one Arrow table."""
        if not self.payloads:
            return
        payloads, log_times, publish_times = self.payloads, self.log_times, self.publish_times
        self.payloads, self.log_times, self.publish_times = [], [], []
        self.pending_bytes = 0
        try:
            times = [pa.array(log_times, pa.int64()), pa.array(publish_times, pa.int64())]
        except OverflowError:  # MCAP times are u64; epoch nanoseconds past 2**63 are damage
            keep = [i for i, t in enumerate(zip(log_times, publish_times, strict=True)) if max(t) < 1 << 63]
            self.warnings.append(
                f"{self.topic}: {len(payloads) - len(keep)} messages with a time past 2**63 ns "
                "(damaged); dropped"
            )
            payloads = [payloads[i] for i in keep]
            times = [pa.array([ts[i] for i in keep], pa.int64()) for ts in (log_times, publish_times)]
            if not payloads:
                return
        table, kept = self._decode(payloads)
        if kept is not None:
            times = [column.take(pa.array(kept, pa.int64())) for column in times]
        names = [n if n not in TIME_COLUMNS else f"payload.{n}" for n in table.column_names]
        self.tables.append(pa.Table.from_arrays([*times, *table.columns], names=[*TIME_COLUMNS, *names]))

    def _decode(self, payloads: list[bytes]) -> tuple[pa.Table, list[int] | None]:
        """Columns of the payloads, and the indices kept when some rows had to be dropped."""
        text = b"\n".join(payloads)
        unsafe = []  # for pyarrow: it takes invalid UTF-8 in a key, then cannot name the column
        if not _valid_utf8(text):
            unsafe.append("invalid UTF-8")
        if _max_line_depth(text) > MAX_JSON_DEPTH:
            unsafe.append(f"nested deeper than {MAX_JSON_DEPTH} levels")
        if unsafe:
            return self._decode_rows(payloads, ", ".join(unsafe))
        parse = pa_json.ParseOptions(explicit_schema=self._explicit, unexpected_field_behavior="infer")
        read = pa_json.ReadOptions(block_size=max(len(text) + 1, 1 << 20))
        try:
            table = pa_json.read_json(pa.py_buffer(text), read_options=read, parse_options=parse)
            if table.num_rows == len(payloads):
                return table, None
            problem = f"{table.num_rows} rows from {len(payloads)} payloads"
        except pa.ArrowException as error:
            problem = str(error).splitlines()[0]
        return self._decode_rows(payloads, problem)

    def _decode_rows(self, payloads: list[bytes], problem: str) -> tuple[pa.Table, list[int]]:
        rows: list[dict[str, Any]] = []
        kept: list[int] = []
        too_deep = 0
        for i, payload in enumerate(payloads):
            if _max_line_depth(payload, lines=False) > MAX_JSON_DEPTH:
                too_deep += 1
                continue
            try:
                row = json.loads(payload)
            except (ValueError, RecursionError):
                continue
            if isinstance(row, dict):
                rows.append(row)
                kept.append(i)
        not_objects = len(payloads) - len(rows) - too_deep
        note = f"; {not_objects} messages were not JSON objects and were dropped" if not_objects else ""
        if too_deep:
            note += f"; {too_deep} messages nested deeper than {MAX_JSON_DEPTH} levels were dropped"
        self.warnings.append(
            f"{self.topic}: a batch did not parse as columns ({problem}); decoded row by row{note}"
        )
        columns: dict[str, list[Any]] = {}
        for n, row in enumerate(rows):
            for key in row:
                columns.setdefault(key, [None] * n)
            for key, values in columns.items():
                values.append(row.get(key))
        arrays = []
        for key, values in columns.items():
            explicit = (
                self._explicit.field(key).type if self._explicit and key in self._explicit.names else None
            )
            arrays.append(_array_or_json_text(values, explicit))
        return pa.Table.from_arrays(arrays, names=list(columns)) if columns else pa.table({}), kept

    def frame(self) -> pd.DataFrame:
        """All messages of the topic as a DataFrame sorted by log time (stable)."""
        self.decode_pending()
        tables, self.tables = self.tables, []
        if not tables:
            return empty_frame(self.topic)
        try:
            table = pa.concat_tables(tables, promote_options="permissive")
        except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError) as error:
            self.warnings.append(
                f"{self.topic}: columns changed type between batches ({error}); combined in pandas"
            )
            frames = [table_to_frame(t, nullable_integer_fields(self.topic)) for t in tables]
            return _sorted(pd.concat(frames))
        return table_to_frame(table, nullable_integer_fields(self.topic))


def _valid_utf8(text: bytes) -> bool:
    if text.isascii():
        return True
    try:
        text.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


def _max_line_depth(text: bytes, *, lines: bool = True) -> int:
    """The deepest nesting of brackets in any line of `text` (in all of it if not `lines`).

    Brackets inside strings count too, and unbalanced ones carry over to the end of their line.
    Computed in blocks, so that the arrays stay small whatever the text.
    """
    brackets = text.translate(None, _NOT_BRACKETS)
    deepest = level = line_level = 0  # the running level, and the level where the current line began
    for start in range(0, len(brackets), _DEPTH_BLOCK):
        codes = np.frombuffer(brackets, np.uint8, min(_DEPTH_BLOCK, len(brackets) - start), start)
        levels = level + np.cumsum(_DEPTH_STEP[codes], dtype=np.int64)
        depths = levels - line_level
        if lines:
            newline = codes == ord("\n")
            if newline.any():  # from its last newline on, a position is measured from that newline's level
                last = np.maximum.accumulate(np.where(newline, np.arange(codes.size), -1))
                depths = np.where(last >= 0, levels - levels[np.maximum(last, 0)], depths)
                if last[-1] >= 0:
                    line_level = int(levels[last[-1]])
        deepest = max(deepest, int(depths.max()))
        level = int(levels[-1])
    return deepest


def _array_or_json_text(values: list[Any], explicit: pa.DataType | None) -> pa.Array:
    """An Arrow array of the values; values of mixed kinds become their JSON text."""
    for arrow_type in (explicit, None):
        try:
            return pa.array(values, type=arrow_type)
        except (pa.ArrowException, TypeError, ValueError, OverflowError):
            continue
    return pa.array([None if v is None else json.dumps(v) for v in values], type=pa.string())


def _flatten(table: pa.Table) -> pa.Table:
    while any(pa.types.is_struct(field.type) for field in table.schema):
        table = table.flatten()
    return table


def nullable_integer_fields(topic: str) -> frozenset[str]:
    """Top-level integer fields of a rig topic that may be missing (not required by its schema)."""
    spec = schemas.TOPICS.get(topic)
    if spec is None:
        return frozenset()
    required = set(spec.schema.get("required", ()))
    return frozenset(
        name
        for name, sub in spec.schema["properties"].items()
        if "integer" in schemas.json_types(sub) and name not in required
    )


def table_to_frame(table: pa.Table, nullable: frozenset[str] = frozenset()) -> pd.DataFrame:
    """A DataFrame indexed by UTC log time: `{sec, nsec}` and other objects flattened to `a.b` columns.

    Integer columns with nulls, and those named in `nullable`, become pandas' nullable `Int64`
    (so the dtype does not depend on the data and epoch nanoseconds stay exact).
    """
    table = _flatten(table)
    log_times = table.column("log_time_ns").to_numpy()
    if log_times.size > 1 and bool((np.diff(log_times) < 0).any()):
        table = table.take(pa.array(np.argsort(log_times, kind="stable")))
    index = pd.DatetimeIndex(
        pd.to_datetime(table.column("log_time_ns").to_numpy(), unit="ns", utc=True), name="log_time"
    )
    order = table.column_names
    integer_columns: dict[str, pd.api.extensions.ExtensionArray] = {}
    for field in table.schema:
        column = table.column(field.name)
        if pa.types.is_integer(field.type) and (column.null_count > 0 or field.name in nullable):
            values = column.fill_null(0).to_numpy().astype(np.int64, copy=False)
            mask = column.is_null().to_numpy(zero_copy_only=False)
            integer_columns[field.name] = pd.arrays.IntegerArray(values, mask)
    if integer_columns:
        table = table.drop_columns(list(integer_columns))
    # self_destruct frees each Arrow column once converted (callers hand over their last reference)
    frame = table.to_pandas(self_destruct=True, split_blocks=True)
    del table
    for name, values in integer_columns.items():
        frame[name] = values
    frame = frame[order]
    frame.index = index
    return frame


def _sorted(frame: pd.DataFrame) -> pd.DataFrame:
    order = np.argsort(frame["log_time_ns"].to_numpy(), kind="stable")
    return frame.iloc[order]


def empty_frame(topic: str) -> pd.DataFrame:
    """The empty DataFrame of a topic with no messages (declared columns for rig topics)."""
    explicit = arrow_schema(topic)
    fields = [pa.field(n, pa.int64()) for n in TIME_COLUMNS] + (list(explicit) if explicit else [])
    return table_to_frame(pa.schema(fields).empty_table(), nullable_integer_fields(topic))


def _plain(value: Any) -> Any:
    """A cell as a plain JSON-like Python value (None for missing)."""
    if value is None or value is pd.NA:
        return None
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and value != value:
        return None
    return value


def frame_payloads(frame: pd.DataFrame) -> list[tuple[int, dict[str, Any]]]:
    """The messages of a topic frame as `(log_time_ns, payload)`: flattened `a.b` columns nested again.

    For the low-rate topics that replay decodes into records (`rig.records`); missing values
    are None, numbers plain Python numbers.
    """
    columns = [c for c in frame.columns if c not in TIME_COLUMNS]
    out: list[tuple[int, dict[str, Any]]] = []
    for log_time_ns, *values in frame[["log_time_ns", *columns]].itertuples(index=False, name=None):
        payload: dict[str, Any] = {}
        for column, value in zip(columns, values, strict=True):
            target = payload
            *parents, leaf = column.removeprefix("payload.").split(".")
            for parent in parents:
                nested = target.setdefault(parent, {})
                if not isinstance(nested, dict):
                    break
                target = nested
            else:
                target[leaf] = _plain(value)
        out.append((int(log_time_ns), payload))
    return out
