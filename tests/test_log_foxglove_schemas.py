"""Every `foxglove.*` channel of a link-validation log against Foxglove's published JSON Schemas.

Run with node from tests/ts_reader (`foxglove_check.mjs`: `@foxglove/schemas`' JSON Schemas, Ajv).
Skipped unless `tests/ts_reader/node_modules` holds them (`npm ci --prefix tests/ts_reader`; `.ci/run`
does it). A stricter consumer than the 3D panel (Foxglove's typed readers, a bridge, another
language's decoder) refuses a message the official schema rejects.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from rig.log.format import schemas as S
from tests.test_replay import LINK

TS_READER = Path(__file__).parent / "ts_reader"
FOXGLOVE_TOPICS = {
    t: spec.schema_name for t, spec in S.TOPICS.items() if spec.schema_name.startswith("foxglove.")
}

pytestmark = [
    pytest.mark.subprocess,
    pytest.mark.skipif(
        shutil.which("node") is None
        or not (TS_READER / "node_modules" / "@foxglove" / "schemas").is_dir()
        or not (TS_READER / "node_modules" / "ajv").is_dir(),
        reason="needs node and `npm ci --prefix tests/ts_reader` (@foxglove/schemas, ajv)",
    ),
]


@pytest.fixture(scope="module")
def link_log(tmp_path_factory, run_on_simulated_rig) -> Path:
    root = tmp_path_factory.mktemp("foxglove")
    protocol = root / "link_small.yaml"
    protocol.write_text(LINK)
    report, _ = run_on_simulated_rig(protocol, root / "logs", run_id="link")
    assert report.exit_code == 0
    return Path(report.log)


def test_the_rig_logs_three_foxglove_topics():
    assert FOXGLOVE_TOPICS == {
        S.LOG: "foxglove.Log",
        S.LINK_FRAMES: "foxglove.FrameTransforms",
        S.LINK_SCENE: "foxglove.SceneUpdate",
    }


def test_every_foxglove_message_of_a_link_validation_log_validates_against_the_official_schema(link_log):
    done = subprocess.run(
        ["node", str(TS_READER / "foxglove_check.mjs"), str(link_log)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=TS_READER,
    )
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout)
    assert found["unknown_schemas"] == []
    assert {topic: entry["schema"] for topic, entry in found["topics"].items()} == FOXGLOVE_TOPICS
    for topic, entry in found["topics"].items():
        assert entry["messages"] > 0, topic
        assert (entry["invalid"], entry["errors"]) == (0, []), topic
    # The schema each channel carries requires everything the official one requires.
    assert found["schema_gaps"] == {topic: [] for topic in FOXGLOVE_TOPICS}
