"""The package's import graph has no circles and no upward imports (scripts/import_graph.py, which
documents the layers), and the tool itself finds both where they are."""
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("import_graph", ROOT / "scripts" / "import_graph.py")
graph = importlib.util.module_from_spec(_spec)
sys.modules["import_graph"] = graph  # its dataclass looks itself up there
_spec.loader.exec_module(graph)


def _show(found, pick):
    return "\n".join(f"{e.source}:{e.line} -> {e.target}" for e in pick(found))


@pytest.fixture(scope="module")
def package_graph():
    return graph.edges(ROOT / "mavattitude", "mavattitude")


def test_the_package_has_no_import_circle_and_no_upward_import(package_graph):
    modules, found = package_graph
    assert len(modules) > 50 and len(found) > 300  # the whole package was read
    assert graph.cycles(modules, found) == [], "an import circle (run scripts/import_graph.py)"
    assert graph.upward(found) == [], "upward imports:\n" + _show(found, graph.upward)


def test_every_module_has_a_layer(package_graph):
    modules, _ = package_graph
    for name in modules:
        graph.layer_of(name)  # raises for a module the table does not place


def _write(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / "pkg" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root / "pkg"


def test_the_tool_finds_a_circle_through_a_lazy_import_and_not_through_a_type_only_one(tmp_path):
    root = _write(tmp_path, {
        "__init__.py": "",
        "a.py": "from . import b\n",
        "b.py": "def f():\n    from .c import thing\n",  # in a function: still ties the files
        "c.py": "from .a import x\n",
        "d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import x\nfrom .e import y\n",
        "e.py": "import pkg.d\n",
    })
    modules, found = graph.edges(root, "pkg")
    assert graph.cycles(modules, found) == [["a", "b", "c"], ["d", "e"]]
    assert ("b", "c", True) in {(e.source, e.target, e.lazy) for e in found}
    assert not any(e.source == "d" and e.target == "a" for e in found)


def test_the_tool_finds_an_upward_import(monkeypatch, tmp_path):
    root = _write(tmp_path, {"__init__.py": "", "low.py": "from .high import x\n", "high.py": "",
                             "sub/__init__.py": "", "sub/inner.py": "from .. import high\n"})
    monkeypatch.setattr(graph, "LAYERS", [("bottom", ["low", "sub"]), ("top", ["high", ""])])
    modules, found = graph.edges(root, "pkg")
    assert [(e.source, e.target) for e in graph.upward(found)] == [("low", "high"), ("sub.inner", "high")]
    monkeypatch.setattr(graph, "LAYERS", [("bottom", ["low"])])
    with pytest.raises(KeyError, match="has no layer"):
        graph.upward(found)
