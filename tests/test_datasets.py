"""GTSAM's example data by name (rlpgo_gtsam.datasets, rlpgo-example): every pose graph listed
reads as stated and the default certifies it; an unknown name is one line listing them; the
wheel's TORO files are refused with their line; a fresh clone's first command runs on them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import gtsam
import pytest
from click.testing import CliRunner
from rlpgo_cli.example import main as example_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import (
    G2oFormatError,
    InputNotFoundError,
    example_file,
    example_names,
    read_g2o,
    staged_initialize,
)
from rlpgo_gtsam.datasets import EXAMPLES
from rlpgo_gtsam.groups import graph_group
from tests.conftest import cli_error, cli_ok


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda e: e.name)
def test_every_listed_example_reads_as_stated_and_certifies(example):
    from rlpgo_gtsam import read_pyfg

    path = example_file(example.name)
    graph, values = read_pyfg(path) if path.endswith(".pyfg") else read_g2o(path)
    assert graph_group(graph).dimension == example.dimension
    assert (values.size(), graph.size()) == (example.poses + example.points,
                                             example.edges + example.measurements)
    run = staged_initialize(graph, values, budget_s=30)
    assert run.certified == example.certified
    assert run.best.refined_chi2 <= 2 * graph.error(values) + 1e-12


def test_a_name_resolves_as_gtsam_resolves_it():
    path = example_file("pose3example-grid.txt")
    assert path == gtsam.findExampleDataFile("pose3example-grid.txt")
    assert example_file("pose3example-grid") == path  # without its extension, as GTSAM takes it
    assert Path(path).is_file()
    assert example_names(2) == ["noisyToyGraph.txt", "pose2example.txt",
                                "victoriaPark_reduced_1k.g2o", "cityTrees_reduced_1k.g2o",
                                "goats_16.pyfg", "goats_15.pyfg"]
    assert set(example_names()) == {example.name for example in EXAMPLES}


@pytest.mark.parametrize("name", ["no_such_graph.g2o", "", "..", "../Data/pose2example.txt",
                                  "Balbianello", "pose2example.txt/"])
def test_an_unknown_name_is_one_line_listing_the_examples(name):
    with pytest.raises(InputNotFoundError) as raised:
        example_file(name)
    message = str(raised.value)
    assert "\n" not in message and "not in GTSAM's example data" in message
    assert "pose2example.txt" in message and "pose3example-grid.txt (" not in message
    assert isinstance(raised.value, FileNotFoundError)


def test_a_name_of_another_type_is_a_type_error():
    with pytest.raises(TypeError, match="file name"):
        example_file(Path("pose2example.txt"))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="dimension"):
        example_names(4)


@pytest.mark.parametrize(("name", "tag"), [("w100_30.g2o", "VERTEX2"), ("w20000.txt", "EDGE2"),
                                           ("sphere2500.txt", "EDGE3")])
def test_the_wheels_toro_files_are_refused_with_their_line(name, tag):
    path = example_file(name)  # in GTSAM's data, not a file this reader takes
    with pytest.raises(G2oFormatError) as raised:
        read_g2o(path)
    assert str(raised.value) == (
        f"{path}:1: unknown tag '{tag}' (TORO's, not g2o's: this reader takes "
        + ("VERTEX_SE3:QUAT, EDGE_SE3:QUAT" if tag == "EDGE3" else "VERTEX_SE2, EDGE_SE2")
        + " and FIX)")


def test_the_command_lists_the_examples_and_prints_a_path():
    listing = CliRunner().invoke(example_main, [])
    cli_ok(listing)
    rows = [line.split()[:4] for line in listing.stdout.splitlines()[1:]]
    assert rows == [[e.name, "planar" if e.dimension == 2 else "3D", str(e.poses), str(e.edges)]
                    for e in EXAMPLES]
    found = CliRunner().invoke(example_main, ["Klaus3.g2o"])
    cli_ok(found)
    assert found.stdout == example_file("Klaus3.g2o") + "\n"
    message = cli_error(CliRunner().invoke(example_main, ["sphere"]))
    assert message.startswith("sphere: not in GTSAM's example data; its pose graphs: ")


def test_init_on_a_printed_path_writes_a_certified_3d_guess(tmp_path):
    out = tmp_path / "grid.g2o"
    path = CliRunner().invoke(example_main, ["pose3example-grid.txt"]).stdout.strip()
    result = CliRunner().invoke(init_main, [path, "-o", str(out)])
    cli_ok(result)
    assert "certificate: certified optimal" in result.stdout
    graph, values = read_g2o(out)
    assert graph.size() == 44 and 2 * graph.error(values) == pytest.approx(86.9973, rel=1e-5)


def test_the_console_script_runs_in_a_shell_substitution(tmp_path):
    """The README's form: rlpgo-init "$(rlpgo-example NAME)" -o OUT, as installed."""
    scripts = Path(sys.executable).parent
    if not (scripts / "rlpgo-example").exists():
        pytest.skip("the console scripts are not installed beside this Python")
    out = tmp_path / "toy.g2o"
    done = subprocess.run(
        ["bash", "-euo", "pipefail", "-c",
         f'"{scripts}/rlpgo-init" "$("{scripts}/rlpgo-example" noisyToyGraph)" -o "{out}"'],
        capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.endswith(f"wrote {out}\n") and out.is_file()
