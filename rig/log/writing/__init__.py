"""Writing a run's MCAP log: the batched logger and its writer process."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "writer",
]
