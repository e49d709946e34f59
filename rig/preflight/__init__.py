"""Pre-flight checks (`rig check`): open every device, move nothing unless asked, report each check.

Each check gives a `CheckRow` (pass, warn or fail, what was measured, the fix).
"""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "check_context",
    "config_update",
    "devices",
    "sections",
    "verdicts",
)

# The names users import (`from rig.preflight import CheckContext`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "CheckContext": "check_context",
    "CheckRow": "verdicts",
    "run_sections": "sections",
    "section_names": "sections",
    "Verdict": "verdicts",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
