"""File helpers shared by commands: bounded reading of text, YAML and JSON with clear errors; atomic writes.

Input files are small and written by people or by the rig, so reading is bounded: only regular
files (not FIFOs or devices, which could block or never end), at most `MAX_INPUT_BYTES`
(`MAX_YAML_BYTES` for YAML, whose pure-Python parser is slow), UTF-8, nested at most `MAX_NESTING`
levels, without YAML aliases (an alias bomb expands a few lines into gigabytes) or duplicate keys,
and text without control characters other than tab and newline. Every problem is an `InputError`
naming the file (docs/formats.md, "Limits").
"""

from __future__ import annotations

import json
import os
import re
import stat
import tempfile
from pathlib import Path
from typing import Any

import yaml

from rig.errors import InputError

MAX_INPUT_BYTES = 10 * 1024 * 1024
MAX_YAML_BYTES = 1024 * 1024
MAX_NESTING = 32  # levels of lists and mappings, the top level included

# Characters no input text may hold: C0 controls other than tab, newline and carriage return, DEL,
# and unpaired surrogates (which YAML and JSON escapes can make, and which cannot be written as UTF-8).
_BAD_TEXT = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff]")


def _size(n: int) -> str:
    return f"{n / (1024 * 1024):g} MiB" if n >= 1024 * 1024 else f"{n} bytes"


def read_text_file(
    path: str | os.PathLike[str], *, what: str = "a text file", max_bytes: int = MAX_INPUT_BYTES
) -> str:
    """The whole of a UTF-8 text file; `InputError` naming the file when it cannot be read.

    `what` completes "allowed: ..." in the messages (e.g. "a CSV file"). Only regular files of at
    most `max_bytes` are read. A leading byte-order mark, as some Windows editors write, is dropped.
    """
    p = Path(path)
    allowed = f"{what} (a regular file of at most {_size(max_bytes)})"
    try:
        # stat before opening: opening a FIFO blocks, and opening a serial device can toggle its lines.
        mode = os.stat(p).st_mode
        if stat.S_ISDIR(mode):
            raise InputError(f"{p}: is a directory; allowed: {what}")
        if not stat.S_ISREG(mode):
            raise InputError(f"{p}: not a regular file (a FIFO, device or socket); allowed: {allowed}")
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced since the stat above
                raise InputError(f"{p}: not a regular file; allowed: {allowed}")
            chunks: list[bytes] = []
            remaining = max_bytes + 1
            while remaining > 0:
                chunk = os.read(fd, min(remaining, 1024 * 1024))
                if not chunk:
                    break
                chunks.append(chunk)
                remaining -= len(chunk)
        finally:
            os.close(fd)
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(f"{p}: cannot read ({reason})") from None
    data = b"".join(chunks)
    if len(data) > max_bytes:
        raise InputError(f"{p}: larger than {_size(max_bytes)}; allowed: {allowed}")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(
            f"{p}: not UTF-8 text (byte 0x{data[exc.start]:02x} at line {line}); allowed: {what}"
        ) from None


def check_tree(data: Any, source: str) -> None:
    """Check parsed data for the bounds every input shares: nesting depth and clean text.

    Raises `InputError` naming `source` and the field path of the first problem.
    """
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        value, path, depth = stack.pop()
        if isinstance(value, str):
            _check_text(value, source, path)
            continue
        if isinstance(value, dict):
            items: list[tuple[str, Any]] = []
            for key, item in value.items():
                if isinstance(key, str):
                    _check_text(key, source, path, key=True)
                items.append((f"{path}.{key}" if path else str(key), item))
        elif isinstance(value, list | tuple):
            items = [(f"{path}[{i}]", item) for i, item in enumerate(value)]
        else:
            continue
        if depth >= MAX_NESTING:
            raise InputError(
                f"{source}: {path or 'top level'}: nested too deeply; allowed: at most {MAX_NESTING} "
                "levels of lists and mappings"
            )
        stack.extend((item, item_path, depth + 1) for item_path, item in items)


def _check_text(text: str, source: str, path: str, *, key: bool = False) -> None:
    bad = _BAD_TEXT.search(text)
    if bad is not None:
        where = path or "top level"
        what = "a key" if key else "text"
        raise InputError(
            f"{source}: {where}: {what} containing {bad.group()!r}; allowed: printable UTF-8 text "
            "(tab and newline allowed)"
        )


def _first_clause(exc: Exception) -> str:
    """The start of an exception's message (Python's own ones can run on with advice)."""
    return str(exc).split(";")[0].strip()


class _Refused(yaml.MarkedYAMLError):
    """Valid YAML that the rig's input files do not allow (aliases, deep nesting, duplicate keys)."""


class _BoundedLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` without aliases, with bounded nesting and with duplicate keys refused."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        """Compose one node; refuse aliases and containers nested deeper than `MAX_NESTING`."""
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()  # type: ignore[no-untyped-call]
            raise _Refused(
                problem=f"alias *{event.anchor}; allowed: plain values (anchors and aliases are not "
                "supported, write the value out)",
                problem_mark=event.start_mark,
            )
        if not self.check_event(yaml.SequenceStartEvent, yaml.MappingStartEvent):
            return super().compose_node(parent, index)
        if self._depth >= MAX_NESTING:
            raise _Refused(
                problem=f"nested too deeply; allowed: at most {MAX_NESTING} levels of lists and mappings",
                problem_mark=self.peek_event().start_mark,  # type: ignore[no-untyped-call]
            )
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        """Construct a mapping; a key given twice is refused, naming the key and both lines."""
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:
                    continue  # unhashable: the base class says so
                if first is not None:
                    raise _Refused(
                        problem=f"duplicate key {key!r} (first at line {first}); allowed: each key once",
                        problem_mark=key_node.start_mark,
                    )
                seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, source: str) -> Any:
    """Parse YAML text read from `source`; malformed YAML is an `InputError` naming it and the place."""
    try:
        data = yaml.load(text, Loader=_BoundedLoader)  # a SafeLoader subclass
    except _Refused as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise InputError(f"{source}: {where}{exc.problem}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise InputError(f"{source}: malformed YAML{where}: {problem}") from None
    except (ValueError, OverflowError) as exc:  # e.g. a date like 2026-02-30, an integer of 5000 digits
        raise InputError(f"{source}: unreadable YAML value ({_first_clause(exc)})") from None
    check_tree(data, source)
    return data


def load_yaml_file(path: str | os.PathLike[str], *, what: str = "a YAML file") -> Any:
    """Read and parse a YAML file; every problem is an `InputError` naming the file."""
    return parse_yaml(read_text_file(path, what=what, max_bytes=MAX_YAML_BYTES), str(Path(path)))


class _JsonRefused(Exception):
    """Valid JSON that the rig's input files do not allow (a duplicate key, NaN or Infinity)."""


def _json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj: dict[str, Any] = {}
    for key, value in pairs:
        if key in obj:
            raise _JsonRefused(f"duplicate key {key!r}; allowed: each key once")
        obj[key] = value
    return obj


def _no_constants(name: str) -> float:
    raise _JsonRefused(f"{name} is not a JSON number; allowed: finite numbers, or null")


def parse_json(text: str, source: str, *, allow_nan: bool = False) -> Any:
    """Parse JSON text read from `source`; every problem is an `InputError` naming it.

    Duplicate keys are refused; so are `NaN` and `Infinity` unless `allow_nan` (Python's json
    module writes them unless told not to).
    """
    try:
        data = json.loads(
            text, object_pairs_hook=_json_object, parse_constant=float if allow_nan else _no_constants
        )
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{source}: malformed JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except _JsonRefused as exc:
        raise InputError(f"{source}: {exc}") from None
    except RecursionError:
        raise InputError(
            f"{source}: nested too deeply; allowed: at most {MAX_NESTING} levels of lists and objects"
        ) from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise InputError(f"{source}: unreadable JSON value ({_first_clause(exc)})") from None
    check_tree(data, source)
    return data


def load_json_file(
    path: str | os.PathLike[str], *, what: str = "a JSON file", allow_nan: bool = False
) -> Any:
    """Read and parse a JSON file; every problem is an `InputError` naming the file."""
    return parse_json(read_text_file(path, what=what), str(Path(path)), allow_nan=allow_nan)


def check_out_dir(out: Path, *, must_exist: bool = False) -> None:
    """`--out` is a directory we may write in, or one we could make; InputError (one line) if not.

    The one `--out` rule of every command: an existing `out` must be a writable directory; a
    missing one needs its nearest existing ancestor to be a writable directory (and is refused
    when `must_exist`, as a resume's is). Nothing is made here.
    """
    allowed = "allowed: a directory for the run's files"
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing == out:
        if not out.is_dir():
            raise InputError(f"--out {out}: not a directory; {allowed}")
        if not os.access(out, os.W_OK | os.X_OK):
            raise InputError(f"--out {out}: not writable")
        return
    if must_exist:
        raise InputError(f"--out {out}: no such directory; nothing to resume there")
    if not existing.is_dir():
        raise InputError(f"--out {out}: {existing} is not a directory; {allowed}")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"--out {out}: {existing} is not writable, so it cannot be made there; {allowed}")


def current_umask() -> int:
    """The process's umask (read by setting it and setting it back: there is no call that only reads it)."""
    umask = os.umask(0o077)
    os.umask(umask)
    return umask


def plain_file_mode(path: str | os.PathLike[str]) -> int:
    """The permission bits a file written at `path` should have: as a plain `open()` would make it.

    An existing file keeps its mode (a rewritten config stays as shared as it was); a new one gets
    0o666 less the umask. `mkstemp`, which the atomic writers use, makes every file 0o600 instead,
    which a second account in a shared lab cannot read.
    """
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        return 0o666 & ~current_umask()


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write `text` to `path` so that readers see the old or the new file, never a partial one.

    The file gets the mode a plain `open()` would give it (`plain_file_mode`).
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    mode = plain_file_mode(p)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
