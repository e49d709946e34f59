"""Write what `rig check --move` measured (reel direction, line stiffness) into a rig config file.

The file's own text is edited line by line, so its comments and layout stay: an existing top-level
`reel_direction:` or `line_stiffness_n_per_m:` line gets the new value (its comment kept), a missing
one is added after `spool_radius_m:`. The new text is validated as a rig config before it replaces
the file, atomically: the file is the old one or the new one, never half written.
"""

from __future__ import annotations

import re
from pathlib import Path

from rig.errors import ConfigError
from rig.inputs.files import atomic_write_text, parse_yaml
from rig.inputs.rig_config import RigConfig, parse_rig_config
from rig.sim.settings import check_simulation

_ANCHOR = "spool_radius_m"


def updated_text(text: str, values: dict[str, str]) -> str:
    """`text` with each top-level `key: value` of `values` set (replaced in place, else added)."""
    lines = text.splitlines(keepends=True)
    for key, value in values.items():
        pattern = re.compile(rf"^{re.escape(key)}:[^#\n]*(#.*)?$")
        for i, line in enumerate(lines):
            match = pattern.match(line.rstrip("\n"))
            if match:
                comment = f"  {match.group(1)}" if match.group(1) else ""
                lines[i] = f"{key}: {value}{comment}\n"
                break
        else:
            anchor = next((i for i, line in enumerate(lines) if line.startswith(f"{_ANCHOR}:")), None)
            new_line = f"{key}: {value}  # measured by rig check --move\n"
            if anchor is None:
                if lines and not lines[-1].endswith("\n"):
                    lines[-1] += "\n"
                lines.append(new_line)
            else:
                lines.insert(anchor + 1, new_line)
    return "".join(lines)


# A measured stiffness within this fraction of the config's is not worth a change of the file.
STIFFNESS_CHANGE_FRACTION = 0.10


def pending_changes(
    config: RigConfig, reel_direction: int | None, stiffness_n_per_m: float | None
) -> dict[str, str]:
    """The `key: value` changes the findings call for (empty: the config already agrees)."""
    values: dict[str, str] = {}
    if reel_direction is not None and reel_direction != config.reel_direction:
        values["reel_direction"] = str(reel_direction)
    nominal = config.line_stiffness_n_per_m
    if (
        stiffness_n_per_m is not None
        and abs(stiffness_n_per_m - nominal) > STIFFNESS_CHANGE_FRACTION * nominal
    ):
        values["line_stiffness_n_per_m"] = f"{stiffness_n_per_m:.0f}"
    return values


def write_changes(config: RigConfig, values: dict[str, str]) -> list[str]:
    """Set `values` in the config's file (validated first, written atomically); returns them as lines."""
    if not values:
        return []
    path = Path(config.source)
    text = updated_text(config.text, values)
    # The new file must be a valid config with exactly these values, or nothing is written.
    new = parse_rig_config(parse_yaml(text, str(path)), source=str(path), text=text, base_dir=path.parent)
    check_simulation(new)
    wanted_direction = int(values.get("reel_direction", config.reel_direction))
    wanted_stiffness = float(values.get("line_stiffness_n_per_m", config.line_stiffness_n_per_m))
    if new.reel_direction != wanted_direction or new.line_stiffness_n_per_m != wanted_stiffness:
        raise ConfigError(
            f"{path}: could not set {', '.join(values)} by editing its lines (a key given twice, or inside "
            "a flow mapping?); edit the file by hand; it was not changed"
        )
    atomic_write_text(path, text)
    return [f"{key}: {value}" for key, value in values.items()]
