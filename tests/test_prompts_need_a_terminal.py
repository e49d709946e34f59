"""A hardware run whose steps wait for a person is refused without a terminal, and only then.

Forks bend and straighten the link themselves: a fork rig's link-validation run waits for nobody
(before, its bend and reset steps were counted as a person's and the run refused over ssh without
-t). With `configuration.source: operator` the measurement and the question after a slip do wait.
"""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from rig.hw.loadcell.calibration import Calibration
from tests.helpers import bare_protocol, shipped_block

ROOT = Path(__file__).resolve().parent.parent
TEMPLATE = ROOT / "protocols" / "rigs" / "hardware.example.yaml"
# Joint estimation with the hook already hung (no prompt), then two configurations bent and reset.
PROTOCOL = bare_protocol(
    "no-prompts",
    [
        shipped_block("smoke", distances_m=[0.12, 0.2], steps=["tare", "ramp_until_slip", "unload"]),
        shipped_block(
            "link_validation",
            1,
            configurations_deg=[[5, 0, 5, 5, 0, 0, 0, 0], [5, 5, 0, 0, 0, 0, 0, 0]],
            steps=["bend", "measure", "tare", "ramp_until_slip", "unload", "reset"],
        ),
    ],
)
FORKS = "\n".join(
    [
        "servos:",
        "  port: /dev/null/no-such-adapter",
        "  baud: 1000000",
        "  ids:",
        "    - {id: 1, role: winch, model: XM430-W350}",
        *(f"    - {{id: {c + 1}, role: bender, model: XM430-W350, component: {c}}}" for c in range(1, 9)),
        "bending:",
        "  pinion_radius_m: 0.01",
        "",
    ]
)


def _rig(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "hw.yaml"
    text = TEMPLATE.read_text(encoding="utf-8")
    text = text[: text.index("\nservos:") + 1] + extra + text[text.index("\nloadcell:") + 1 :]
    path.write_text(text, encoding="utf-8")
    Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-29", "test", "rig-lc1").save(
        tmp_path / "loadcell-cal.json"
    )
    return path


HANDS = "\n".join(
    [
        "servos:",
        "  port: /dev/null/no-such-adapter",
        "  baud: 1000000",
        "  ids:",
        "    - {id: 1, role: winch, model: XM430-W350}",
        "    - {id: 2, role: bender, model: XM430-W350}",
        "",
    ]
)


@pytest.mark.parametrize(
    ("extra", "waits"),
    [
        (FORKS, None),  # the forks bend and reset; nothing else in the protocol prompts
        (FORKS + "configuration: {source: operator}\n", "measure, ramp_until_slip"),
        (HANDS, "bend, reset"),  # no forks: the link is bent and straightened by hand
    ],
)
def test_only_steps_a_person_does_need_a_terminal(tmp_path, run_cli, monkeypatch, extra, waits):
    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # not a terminal (ssh without -t, cron)
    protocol = tmp_path / "p.yaml"
    protocol.write_text(PROTOCOL, encoding="utf-8")
    result = run_cli("run", protocol, "--rig", _rig(tmp_path, extra), "--out", tmp_path / "out")
    refused = "wait for the operator to press Enter, and stdin is not a terminal" in result.err
    if waits is None:
        assert not refused, result.err
        assert result.code != 0  # it got as far as the devices, which do not exist here
    else:
        assert refused and result.code == 2 and f"its {waits} steps wait" in result.err, result.err
