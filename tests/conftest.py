"""Test-wide settings."""

import os

# Every payload a test logs is checked against its topic schema (rig/log/schemas.py).
os.environ.setdefault("RIG_LOG_STRICT", "1")
