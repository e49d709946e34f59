"""The protocol runner: plan, state machine, interlocks, journal, and the trial loop."""
