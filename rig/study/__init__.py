"""`rig study`: a protocol run on the simulated rig over many seeds, scored against the world's truth.

Layer: between `rig.cli` and `rig.rigs` (it composes simulated rigs through `rig.rigs`).
"""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "executor",
    "seeds",
    "statistics",
    "table",
    "worker",
)

# The names users import (`from rig.study import StudySpec`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "run_dask": "executor",
    "run_local": "executor",
    "run_seed": "worker",
    "StudySpec": "worker",
    "summarise": "statistics",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
