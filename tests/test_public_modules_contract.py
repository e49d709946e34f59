"""The "private modules stay private" import contract: it finds leaks, and every package names its surface."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import sys
from pathlib import Path

import grimp
import pytest

import model
import rig

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from tools.public_modules_contract import PublicModulesContract, declared_public  # noqa: E402


def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def _check(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, files: dict[str, str]):
    _write(tmp_path, files)
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    graph = grimp.build_graph("toypkg", cache_dir=None)
    contract = PublicModulesContract(
        name="private modules stay private", session_options={}, contract_options={"containers": ["toypkg"]}
    )
    return contract.check(graph, verbose=False)


TOY = {
    "toypkg/__init__.py": "PUBLIC_MODULES = ('api', 'inner')\n",
    "toypkg/api.py": "from toypkg.inner import shown\n",
    "toypkg/inner/__init__.py": "PUBLIC_MODULES = ('shown',)\n",
    "toypkg/inner/shown.py": "from toypkg.inner import hidden\n",  # a sibling: allowed
    "toypkg/inner/hidden.py": "X = 1\n",
    "toypkg/inner/deeper/__init__.py": "PUBLIC_MODULES: tuple[str, ...] = ()\n",
    "toypkg/inner/deeper/user.py": "from toypkg.inner.hidden import X\n",  # inside the package: allowed
}


def test_a_package_that_keeps_its_private_modules_private_keeps_the_contract(tmp_path, monkeypatch):
    check = _check(tmp_path, monkeypatch, TOY)
    assert check.kept, check.metadata


def test_an_import_of_a_private_module_from_outside_its_package_breaks_it(tmp_path, monkeypatch):
    leaky = {
        **TOY,
        "toypkg/api.py": "from toypkg.inner.hidden import X\n",
        "toypkg/other.py": "import toypkg.api\n",
    }
    check = _check(
        tmp_path, monkeypatch, {**leaky, "toypkg/__init__.py": "PUBLIC_MODULES = ('api', 'inner', 'other')\n"}
    )
    assert not check.kept
    ((importer, imported, line),) = [
        (v.importer, v.imported, v.line_number) for v in check.metadata["violations"]
    ]
    assert (importer, imported, line) == ("toypkg.api", "toypkg.inner.hidden", 1)
    assert check.metadata["undeclared"] == []


def test_a_package_without_public_modules_breaks_it(tmp_path, monkeypatch):
    check = _check(
        tmp_path, monkeypatch, {**TOY, "toypkg/inner/deeper/__init__.py": '"""No surface named."""\n'}
    )
    assert not check.kept and check.metadata["undeclared"] == ["toypkg.inner.deeper"]


def _packages() -> list[str]:
    names = ["rig", "model"]
    for root in (rig, model):
        names += [m.name for m in pkgutil.walk_packages(root.__path__, f"{root.__name__}.") if m.ispkg]
    return names


@pytest.mark.parametrize("package", _packages())
def test_every_public_module_a_package_names_is_one_of_its_modules(package):
    init = importlib.import_module(package)
    public = declared_public(Path(init.__file__))
    assert public is not None, f"{package} names no public modules"
    submodules = {m.name for m in pkgutil.iter_modules(init.__path__)}
    for name in public:
        assert name in submodules, f"{package}.PUBLIC_MODULES names {name!r}, which is not one of its modules"


@pytest.mark.parametrize("package", _packages())
def test_every_name_in_a_packages_all_is_a_name_users_import_not_a_module(package):
    init = importlib.import_module(package)
    names = init.__all__
    assert names, f"{package}.__all__ is empty"
    for name in names:
        value = getattr(init, name)  # loaded from its defining module on first use (rig.exports)
        assert not inspect.ismodule(value), (
            f"{package}.__all__ names the module {name!r}, not a name users import"
        )
    star: dict[str, object] = {}
    exec(f"from {package} import *", star)
    assert set(names) <= set(star)
