"""The package's import graph: layered, no module imports one above it, so no cycles; the
light entry points load neither torch nor gymnasium."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

import rlpgo_gtsam

PACKAGE = Path(rlpgo_gtsam.__file__).parent

README = PACKAGE.parent / "README.md"


def _layers() -> list[str]:
    """The module order of the README's layout table (one place for it), lowest first. A
    module may import only modules listed before it (at top level, inside a function, or
    under TYPE_CHECKING alike). The package root (__init__) is the facade above all."""
    rows = re.findall(r"^\| (\d+) \| `([\w.]+)` \|", README.read_text(), flags=re.MULTILINE)
    assert [int(k) for k, _ in rows] == list(range(1, len(rows) + 1)), "layers numbered 1..N"
    return [name for _, name in rows]


LAYERS = _layers()


def _modules() -> dict[str, Path]:
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        modules[name] = path
    return modules


def _imports(path: Path) -> set[str]:
    """Every rlpgo_gtsam module ``path`` imports, by its name inside the package."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        for name in names:
            if name == "rlpgo_gtsam" or name.startswith("rlpgo_gtsam."):
                found.add(name.removeprefix("rlpgo_gtsam").removeprefix("."))
            if name.split(".")[0] == "rlpgo_cli":
                found.add("<cli>")
    return found


def test_every_module_has_a_layer():
    assert set(_modules()) - {""} == set(LAYERS)


@pytest.mark.parametrize("module", LAYERS)
def test_no_module_imports_one_above_it(module):
    allowed = set(LAYERS[: LAYERS.index(module)])
    imported = _imports(_modules()[module])
    assert imported <= allowed, f"{module} imports {sorted(imported - allowed)}"


def _loaded_after(code: str) -> set[str]:
    script = f"import sys\n{code}\nprint(' '.join(sorted(sys.modules)))"
    output = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            check=True, timeout=120).stdout
    return set(output.split())


@pytest.mark.parametrize("code", [
    "import rlpgo_gtsam; rlpgo_gtsam.read_g2o",
    "import rlpgo_gtsam; rlpgo_gtsam.make_initializer('chordal')",
    "import rlpgo_cli.init, rlpgo_cli.compare, rlpgo_cli.generate, rlpgo_cli.train, "
    "rlpgo_cli.evaluate, rlpgo_cli.example",
])
def test_light_entry_points_load_neither_torch_nor_gymnasium(code):
    loaded = _loaded_after(code)
    assert not {"torch", "gymnasium", "matplotlib"} & loaded


def test_the_commands_help_loads_no_scipy():
    """What --help needs (the command modules and the package's errors) stays off scipy,
    the solvers' heavy import: --help answers in under half a second here."""
    loaded = _loaded_after("import rlpgo_cli.init, rlpgo_cli.compare, rlpgo_cli.generate, "
                           "rlpgo_cli.train, rlpgo_cli.evaluate, rlpgo_cli.example, "
                           "rlpgo_gtsam.errors")
    assert not {"scipy", "threadpoolctl", "evo"} & loaded


def test_the_environment_registers_on_first_use():
    loaded = _loaded_after("import gymnasium, rlpgo_gtsam; assert rlpgo_gtsam.ENV_ID in "
                           "gymnasium.registry")
    assert "gymnasium" in loaded and "torch" not in loaded


def test_reading_a_planar_file_loads_no_masked_arrays():
    """numpy 2.4's ``unique`` (under ``np.isin`` too) imports numpy.ma, 4.5 ms of every
    command: the reader's checks and its table of distinct information matrices (MIT's
    differ from edge to edge) do without it."""
    from tests.conftest import dataset

    path = dataset("MIT.g2o")
    loaded = _loaded_after(f"from rlpgo_gtsam.io import read_g2o_extracted\n"
                           f"read_g2o_extracted({str(path)!r})")
    assert "rlpgo_gtsam.io" in loaded and "numpy.ma" not in loaded
