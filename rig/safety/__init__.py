"""Keeping the rig safe: the safe-state sequence, the line's release, the interlocks and Ctrl-C deferral."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "interlocks",
    "interrupts",
    "release",
    "safe_state",
)

# The names users import (`from rig.safety import LineRelease`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "enter_safe_state": "safe_state",
    "interrupts_deferred": "interrupts",
    "interrupts_held": "interrupts",
    "LineRelease": "release",
    "signals_deferred": "interrupts",
    "terminate_as_interrupt": "interrupts",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
