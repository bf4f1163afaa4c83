"""The package's layers: imports flow one way, and the command line stays light.

The benchmark package (``bench/zenoh_perception_bench``: benchmarks, scene generator, demo
camera) sits on top of the service's package, which never imports it but from the command
that runs it; the stress tools (``tools/``, not installed) sit on top of both; nothing imports
the tests."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "zenoh_perception"
BENCH = REPO / "bench"
TOOLS = REPO / "tools"

# Bottom to top: a module may import from its own layer and the layers below it.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("zenoh_perception", "zenoh_perception.errors", "zenoh_perception.resolutions"),
    ("zenoh_perception.tags",),
    ("zenoh_perception.wire",),
    ("zenoh_perception.detect",),
    ("zenoh_perception.settings",),
    ("zenoh_perception.pipeline",),
    ("zenoh_perception.service",),
    ("zenoh_perception.camera",),
    ("zenoh_perception_bench.scene",),
    ("zenoh_perception_bench",),
    ("zenoh_perception.cli", "zenoh_perception.__main__"),
    ("tools",),
)
#: Top-level packages whose imports the layers govern (``tests`` is in none: nothing imports it).
CHECKED = ("zenoh_perception", "zenoh_perception_bench", "tools", "tests")
# The only modules that import inside functions: the command line's handlers, each importing
# its subcommand's module when it runs.
LAZY = frozenset({"zenoh_perception.cli.commands", "zenoh_perception.cli.bench_commands"})
#: No module is longer: past that a reader no longer holds it whole.
MAX_LINES = 700
# Modules still longer than MAX_LINES while they are being split: take each out once it is.
TOO_LONG_FOR_NOW: frozenset[str] = frozenset()


def _module_name(path: Path) -> str:
    root = BENCH if path.is_relative_to(BENCH) else REPO
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _layer(module: str) -> int:
    best = (-1, -1)  # (length of the matching prefix, layer)
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best[0]:
                best = (len(prefix), index)
    assert best[1] >= 0, f"{module} is in no layer"
    return best[1]


def _imports(path: Path) -> list[tuple[str, bool]]:
    """(imported module, imported at the top level) for each import of :data:`CHECKED`."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(node) for node in tree.body}
    found: list[tuple[str, bool]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
            if node.module == "zenoh_perception":
                names = [f"zenoh_perception.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        found += [(n, id(node) in top) for n in names if n.split(".")[0] in CHECKED]
    return found


MODULES = sorted(PACKAGE.rglob("*.py")) + sorted(BENCH.rglob("*.py")) + sorted(TOOLS.rglob("*.py"))


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(REPO)))
def test_imports_flow_down_the_layers(path: Path) -> None:
    module = _module_name(path)
    for imported, at_top in _imports(path):
        if imported == "zenoh_perception.__version__":
            continue
        assert _layer(imported) <= _layer(module), f"{module} imports {imported} from above"
        assert at_top or module in LAZY, f"{module} imports {imported} inside a function"


def test_each_lazy_module_imports_inside_a_function() -> None:
    """The allowance names modules that exist and use it, so it cannot hide a stale name."""
    lazy = {_module_name(path): path for path in MODULES if _module_name(path) in LAZY}
    assert set(lazy) == LAZY
    for path in lazy.values():
        assert any(not at_top for _, at_top in _imports(path)), f"{path} imports nothing late"


def test_the_modules_allowed_to_be_long_exist() -> None:
    assert {path.relative_to(REPO).as_posix() for path in MODULES} >= TOO_LONG_FOR_NOW


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(REPO)))
def test_no_module_is_too_long(path: Path) -> None:
    lines = len(path.read_text(encoding="utf-8").splitlines())
    name = path.relative_to(REPO).as_posix()
    if name in TOO_LONG_FOR_NOW:
        assert lines > MAX_LINES, f"{name} is {lines} lines now: take it out of TOO_LONG_FOR_NOW"
    else:
        assert lines <= MAX_LINES, f"{name} is {lines} lines, more than {MAX_LINES}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(REPO)))
def test_each_module_logs_under_its_own_name(path: Path) -> None:
    """A log line's logger= names the module that wrote it."""
    module = _module_name(path)
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "getLogger"
            and node.args
        ):
            name = node.args[0]
            named = isinstance(name, ast.Name) and name.id == "__name__"
            assert named or (isinstance(name, ast.Constant) and name.value == module), (
                f"{module} logs as {ast.unparse(name)}"
            )


def test_layer_check_catches_an_upward_import() -> None:
    assert _layer("zenoh_perception.service.node") > _layer("zenoh_perception.wire.frames")
    assert _layer("zenoh_perception.detect.opencv") < _layer("zenoh_perception.settings")
    assert _layer("tools.rig") > _layer("zenoh_perception.cli.main")


def test_the_tools_are_found_and_no_layer_holds_the_tests() -> None:
    assert REPO / "tools" / "soak.py" in MODULES
    with pytest.raises(AssertionError, match="in no layer"):
        _layer("tests.helpers")


def test_the_command_line_loads_no_opencv_scene_or_bench() -> None:
    code = (
        "import sys, zenoh_perception.cli.main; "
        "print(' '.join(m for m in sys.modules if m.split('.')[0] in "
        "('cv2', 'zenoh_perception', 'zenoh_perception_bench')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    assert "zenoh_perception.cli.main" in out
    heavy = [m for m in out if m == "cv2" or m.startswith("zenoh_perception_bench")]
    heavy += [m for m in out if m in ("zenoh_perception.service.node", "zenoh_perception.pipeline")]
    assert heavy == []


def test_settings_import_no_detector() -> None:
    code = "import sys, zenoh_perception.settings; print('cv2' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_the_service_package_ships_no_bench_scene_or_demo() -> None:
    assert not (PACKAGE / "bench").exists()
    assert not (PACKAGE / "scene").exists()
    assert not (PACKAGE / "camera" / "demo.py").exists()
    assert _layer("zenoh_perception_bench.scene") > _layer("zenoh_perception.camera")
    pyproject = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    assert 'include = ["zenoh_perception", "zenoh_perception.*"]' in pyproject


@pytest.mark.parametrize("command", ["bench", "demo"])
def test_bench_and_demo_say_how_to_install_the_bench_package(
    command: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import importlib.util

    from zenoh_perception.cli import main

    real = importlib.util.find_spec

    def without_bench(name: str, package: str | None = None) -> object:
        return None if name == "zenoh_perception_bench" else real(name, package)

    monkeypatch.setattr(importlib.util, "find_spec", without_bench)
    assert main.main([command]) == 2
    err = capsys.readouterr().err
    assert "pip install -e ./bench" in err
    assert f"make {command}" in err
