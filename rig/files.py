"""Small file helpers shared by commands: reading text and YAML with clear errors, atomic writes."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import yaml

from rig.errors import InputError


def read_text_file(path: str | os.PathLike[str], *, what: str = "a text file") -> str:
    """The whole of a UTF-8 text file; `InputError` naming the file when it cannot be read.

    `what` completes "allowed: ..." in the messages (e.g. "a CSV file"). A leading byte-order mark,
    as some Windows editors write, is dropped.
    """
    p = Path(path)
    try:
        return p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError(f"{p}: file not found") from None
    except IsADirectoryError:
        raise InputError(f"{p}: is a directory; allowed: {what}") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not UTF-8 text; allowed: {what}") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from None


def parse_yaml(text: str, source: str) -> Any:
    """Parse YAML text read from `source`; malformed YAML is an `InputError` naming it and the place."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise InputError(f"{source}: malformed YAML{where}: {problem}") from None


def load_yaml_file(path: str | os.PathLike[str], *, what: str = "a YAML file") -> Any:
    """Read and parse a YAML file; every problem is an `InputError` naming the file."""
    return parse_yaml(read_text_file(path, what=what), str(Path(path)))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write `text` to `path` so that readers see the old or the new file, never a partial one."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
