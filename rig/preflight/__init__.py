"""Pre-flight checks (`rig check`): open every device, move nothing unless asked, report each check.

Each check gives a `CheckRow` (pass, warn or fail, what was measured, the fix).
"""
