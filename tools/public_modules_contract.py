"""An import-linter contract type: a package's modules not named in its `PUBLIC_MODULES` are private.

Each package's `__init__.py` lists, in `PUBLIC_MODULES`, the submodules other packages may import
(its `__all__` lists the names users import, which is another list). Any other submodule is private
to its package: only modules inside that package (its siblings and its subpackages' modules) may
import it. `PUBLIC_MODULES` is read from the source, not imported, so checking costs no import of
the rig. Registered in pyproject.toml under `[tool.importlinter]`.
"""

from __future__ import annotations

import ast
import importlib.machinery
from dataclasses import dataclass
from pathlib import Path

from importlinter import Contract, ContractCheck, fields, output


@dataclass(frozen=True)
class PrivateImport:
    """One import of a private module from outside its package."""

    importer: str
    imported: str
    line_number: int


# The name of the list, in a package's `__init__.py`, of its modules other packages may import.
PUBLIC_MODULES = "PUBLIC_MODULES"


def declared_public(init_file: Path) -> tuple[str, ...] | None:
    """The names in a package's `PUBLIC_MODULES` (a literal tuple or list of strings), or None without one."""
    tree = ast.parse(init_file.read_text(encoding="utf-8"), filename=str(init_file))
    for node in tree.body:
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            targets = [node.target]
        else:
            targets = []
        if any(isinstance(t, ast.Name) and t.id == PUBLIC_MODULES for t in targets):
            value = ast.literal_eval(node.value)
            if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"{init_file}: {PUBLIC_MODULES} must be a literal tuple of strings")
            return tuple(value)
    return None


def _init_file(package: str) -> Path | None:
    """The `__init__.py` of a package, found on sys.path without importing anything."""
    parts = package.split(".")
    search: list[str] | None = None
    origin: str | None = None
    for depth in range(1, len(parts) + 1):
        spec = importlib.machinery.PathFinder.find_spec(".".join(parts[:depth]), search)
        if spec is None or spec.submodule_search_locations is None:
            return None
        search, origin = list(spec.submodule_search_locations), spec.origin
    return Path(origin) if origin is not None else None


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


class PublicModulesContract(Contract):
    """Packages under `containers` whose `__init__` has `PUBLIC_MODULES`: their other modules stay private.

    A package without `PUBLIC_MODULES` fails the contract, so a new package has to name its surface.
    """

    containers = fields.ListField(subfield=fields.ModuleField())

    def check(self, graph, verbose: bool) -> ContractCheck:  # type: ignore[no-untyped-def]
        roots = [str(c.name) for c in self.containers]  # type: ignore[attr-defined]
        packages = sorted(
            m for m in graph.modules if any(_inside(m, r) for r in roots) and graph.find_children(m)
        )
        undeclared: list[str] = []
        violations: list[PrivateImport] = []
        for package in packages:
            init_file = _init_file(package)
            public = declared_public(init_file) if init_file is not None else None
            if public is None:
                undeclared.append(package)
                continue
            for module in sorted(graph.find_children(package)):
                if module.rsplit(".", 1)[1] in public:
                    continue
                for importer in sorted(graph.find_modules_that_directly_import(module)):
                    if _inside(importer, package):
                        continue
                    for detail in graph.get_import_details(importer=importer, imported=module):
                        violations.append(PrivateImport(importer, module, detail["line_number"]))
        kept = not undeclared and not violations
        output.verbose_print(verbose, f"Checked the surfaces of {len(packages)} packages.")
        return ContractCheck(kept=kept, metadata={"undeclared": undeclared, "violations": violations})

    def render_broken_contract(self, check: ContractCheck) -> None:
        for package in check.metadata["undeclared"]:
            output.print_error(f"{package} has no {PUBLIC_MODULES} naming its public modules.", bold=False)
            output.new_line()
        for v in check.metadata["violations"]:
            output.print_error(
                f"{v.importer} (l. {v.line_number}) imports {v.imported}, which is private: "
                f"add it to {v.imported.rsplit('.', 1)[0]}.{PUBLIC_MODULES} "
                "or import a public module instead.",
                bold=False,
            )
            output.new_line()
