"""Pre-flight checks (`rig check`): open every device, move nothing unless asked, report each check.

Each check gives a `CheckRow` (pass, warn or fail, what was measured, the fix).
"""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "check_context",
    "config_update",
    "devices",
    "sections",
    "verdicts",
]
