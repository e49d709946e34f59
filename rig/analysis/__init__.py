"""Replay and analysis of logged runs: trial tables, re-detection, refits and reports (`rig replay`)."""
