"""The emulated load cell: signal and line formats, and its in-process and pty transports."""
