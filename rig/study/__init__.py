"""`rig study`: a protocol run on the simulated rig over many seeds, scored against the world's truth.

Layer: between `rig.cli` and `rig.rigs` (it composes simulated rigs through `rig.rigs`).
"""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "executor",
    "seeds",
    "statistics",
    "table",
    "worker",
]
