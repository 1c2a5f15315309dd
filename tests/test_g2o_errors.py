"""Every malformed g2o input, through ``read_g2o``; what the reader accepts.

Each case is a small file written into ``tmp_path`` (mostly the valid 3-pose graph ``BASE``
with one line changed) and the exact one-line reason the reader gives for it. The API must
raise :class:`G2oFormatError` with message ``<path>:<line>: <reason>`` (``<path>: <reason>``
where no line applies); the CLI must print exactly ``Error: <message>`` on stderr, exit
non-zero, print no traceback and write no ``--json`` file.

One case runs through each command, and one through the ``rlpgo-compare`` console script as
a real process: the plumbing, not the table again.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam.errors import G2oFormatError, OutputError
from rlpgo_gtsam.io import MAX_LINE_BYTES, read_g2o, write_g2o
from tests.conftest import assert_same_factors, cli_error, factor_rows

INFO = "1 0 0 1 0 1"
BASE_LINES = [
    "VERTEX_SE2 0 0 0 0",  # line 1
    "VERTEX_SE2 1 1 0 0",  # line 2
    "VERTEX_SE2 2 2 0 0",  # line 3
    f"EDGE_SE2 0 1 1 0 0 {INFO}",  # line 4
    f"EDGE_SE2 1 2 1 0 0 {INFO}",  # line 5
    f"EDGE_SE2 0 2 2 0 0 {INFO}",  # line 6
]
BASE = "\n".join(BASE_LINES) + "\n"

UNKNOWN_TAG = "(this reader takes VERTEX_SE2, EDGE_SE2 and FIX)"
NOT_PD = "EDGE_SE2 information matrix is not positive definite"
NO_LINES = "holds no VERTEX_SE2 or EDGE_SE2 line"


# --------------------------------------------------------------------------- file builders


def _write(data: bytes | str) -> Callable[[Path], Path]:
    def build(folder: Path) -> Path:
        path = folder / "graph.g2o"
        path.write_bytes(data.encode() if isinstance(data, str) else data)
        return path

    return build


def replace(line: int, text: str) -> Callable[[Path], Path]:
    """BASE with its 1-based ``line`` replaced by ``text``."""
    lines = list(BASE_LINES)
    lines[line - 1] = text
    return _write("\n".join(lines) + "\n")


def insert(line: int, text: str) -> Callable[[Path], Path]:
    """BASE with ``text`` inserted so that it becomes 1-based ``line``."""
    lines = list(BASE_LINES)
    lines.insert(line - 1, text)
    return _write("\n".join(lines) + "\n")


def raw(data: bytes | str) -> Callable[[Path], Path]:
    return _write(data)


def missing(folder: Path) -> Path:
    return folder / "no_such_graph.g2o"


def directory(folder: Path) -> Path:
    path = folder / "graphs.g2o"
    path.mkdir()
    return path


# --------------------------------------------------------------------------- the case table


@dataclass(frozen=True)
class Case:
    id: str
    build: Callable[[Path], Path]
    line: int | None
    reason: str


EDGE_ONLY_DISCONNECTED = (
    f"EDGE_SE2 0 1 1 0 0 {INFO}\n"
    f"EDGE_SE2 2 3 1 0 0 {INFO}\n"
)

CASES = [
    # field counts
    Case("vertex_too_few_fields", replace(2, "VERTEX_SE2 1 1 0"), 2,
         "VERTEX_SE2 needs 4 numbers after the tag, found 3"),
    Case("vertex_too_many_fields", replace(2, "VERTEX_SE2 1 1 0 0 0"), 2,
         "VERTEX_SE2 needs 4 numbers after the tag, found 5"),
    Case("vertex_tag_only", replace(3, "VERTEX_SE2"), 3,
         "VERTEX_SE2 needs 4 numbers after the tag, found 0"),
    Case("edge_nine_numbers", replace(5, "EDGE_SE2 1 2 1 0 0 1 0 0 1"), 5,
         "EDGE_SE2 needs 11 numbers after the tag, found 9"),
    Case("edge_twelve_numbers", replace(5, f"EDGE_SE2 1 2 1 0 0 {INFO} 7"), 5,
         "EDGE_SE2 needs 11 numbers after the tag, found 12"),
    Case("truncated_last_line", raw("\n".join(BASE_LINES[:5]) + "\nEDGE_SE2 0 2 2 0 0 1 0"), 6,
         "EDGE_SE2 needs 11 numbers after the tag, found 7"),
    Case("crlf_keeps_line_numbers",
         raw("\r\n".join([*BASE_LINES[:4], "EDGE_SE2 1 2 1 0 0 1 0 0 1", BASE_LINES[5]])), 5,
         "EDGE_SE2 needs 11 numbers after the tag, found 9"),
    Case("line_too_long", raw(b"# ok\n" + b"a" * (MAX_LINE_BYTES + 10)), 2,
         f"line longer than {MAX_LINE_BYTES} bytes (not a g2o file?)"),
    # numbers (positions count the fields after the tag, ids included)
    Case("vertex_not_a_number", replace(2, "VERTEX_SE2 1 abc 0 0"), 2,
         "VERTEX_SE2 field 2 is not a number: 'abc'"),
    Case("edge_information_not_a_number", replace(4, "EDGE_SE2 0 1 1 0 0 1 0 0 x 0 1"), 4,
         "EDGE_SE2 field 9 is not a number: 'x'"),
    Case("edge_comma_decimal", replace(4, "EDGE_SE2 0 1 1,5 0 0 1 0 0 1 0 1"), 4,
         "EDGE_SE2 field 3 is not a number: '1,5'"),
    Case("vertex_nan", replace(2, "VERTEX_SE2 1 1 nan 0"), 2,
         "VERTEX_SE2 field 3 is not finite: 'nan'"),
    Case("edge_nan", replace(4, "EDGE_SE2 0 1 1 0 NaN 1 0 0 1 0 1"), 4,
         "EDGE_SE2 field 5 is not finite: 'NaN'"),
    Case("vertex_inf", replace(3, "VERTEX_SE2 2 2 0 inf"), 3,
         "VERTEX_SE2 field 4 is not finite: 'inf'"),
    Case("edge_minus_inf_information", replace(6, "EDGE_SE2 0 2 2 0 0 -inf 0 0 1 0 1"), 6,
         "EDGE_SE2 field 6 is not finite: '-inf'"),
    Case("edge_overflow", replace(5, "EDGE_SE2 1 2 1e999 0 0 1 0 0 1 0 1"), 5,
         "EDGE_SE2 field 3 is not finite: '1e999'"),
    Case("number_with_underscore", replace(2, "VERTEX_SE2 1 1_0 0 0"), 2,
         "VERTEX_SE2 field 2 is not a number: '1_0'"),
    Case("number_with_unicode_digit", replace(2, "VERTEX_SE2 1 \u0661 0 0"), 2,
         "VERTEX_SE2 field 2 is not a number: '\\u0661'"),
    # information matrix
    Case("information_zero_diagonal", replace(4, "EDGE_SE2 0 1 1 0 0 1 0 0 0 0 1"), 4, NOT_PD),
    Case("information_xy_too_large", replace(5, "EDGE_SE2 1 2 1 0 0 1 2 0 1 0 1"), 5, NOT_PD),
    Case("information_negative", replace(6, "EDGE_SE2 0 2 2 0 0 -1 0 0 -1 0 -1"), 6, NOT_PD),
    Case("information_all_zero", replace(6, "EDGE_SE2 0 2 2 0 0 0 0 0 0 0 0"), 6, NOT_PD),
    # ids and references
    Case("duplicate_vertex", insert(4, "VERTEX_SE2 1 5 5 0"), 4,
         "VERTEX_SE2 id 1 defined twice (first on line 2)"),
    Case("edge_to_unknown_vertex", replace(6, f"EDGE_SE2 0 7 2 0 0 {INFO}"), 6,
         "EDGE_SE2 refers to vertex 7, which no VERTEX_SE2 line defines"),
    Case("self_loop", replace(5, f"EDGE_SE2 1 1 0 0 0 {INFO}"), 5,
         "EDGE_SE2 joins vertex 1 to itself"),
    Case("negative_vertex_id", replace(1, "VERTEX_SE2 -1 0 0 0"), 1,
         "vertex id must be a non-negative integer, found '-1'"),
    Case("non_integer_vertex_id", replace(2, "VERTEX_SE2 1.5 1 0 0"), 2,
         "vertex id must be a non-negative integer, found '1.5'"),
    Case("negative_edge_id", replace(4, f"EDGE_SE2 0 -1 1 0 0 {INFO}"), 4,
         "vertex id must be a non-negative integer, found '-1'"),
    Case("vertex_id_too_large", replace(1, "VERTEX_SE2 18446744073709551616 0 0 0"), 1,
         "vertex id 18446744073709551616 is too large"),
    Case("fix_unknown_vertex", insert(7, "FIX 9"), 7,
         "FIX refers to vertex 9, which is not defined"),
    Case("fix_without_id", insert(7, "FIX"), 7, "FIX needs at least one vertex id"),
    Case("fix_bad_id", insert(7, "FIX 0 x"), 7,
         "vertex id must be a non-negative integer, found 'x'"),
    # tags
    # a 3D first pose line makes a 3D file: the planar lines after it are the error
    Case("vertex_se3_quat", replace(1, "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1"), 2,
         "VERTEX_SE2: a planar line in a 3D file (a file holds 2D or 3D lines, not both)"),
    Case("edge_se3_quat",
         replace(4, "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 " + " ".join(["1", "0", "0", "0", "0", "0",
                                                                  "1", "0", "0", "0", "0",
                                                                  "1", "0", "0", "0",
                                                                  "1", "0", "0",
                                                                  "1", "0", "1"])),
         4, "EDGE_SE3:QUAT: a 3D line in a planar file (a file holds 2D or 3D lines, not "
         "both)"),
    Case("unmeasured_vertex_xy", insert(7, "VERTEX_XY 3 1 1"), 7,
         "VERTEX_XY 3: no line measures landmark 3 (an initializer needs a connected graph)"),
    Case("unknown_tag_foo", replace(1, "FOO 1 2 3"), 1, f"unknown tag 'FOO' {UNKNOWN_TAG}"),
    Case("lowercase_tag", replace(2, "vertex_se2 1 1 0 0"), 2,
         f"unknown tag 'vertex_se2' {UNKNOWN_TAG}"),
    # nothing to read
    Case("empty_file", raw(b""), None, NO_LINES),
    Case("only_comments_and_blank_lines", raw("# a header\n\n   \n#no space\n\t\n"), None,
         NO_LINES),
    # connectivity
    Case("disconnected", raw("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 0 5 0\n"
                             f"VERTEX_SE2 3 1 5 0\nEDGE_SE2 0 1 1 0 0 {INFO}\n"
                             f"EDGE_SE2 2 3 1 0 0 {INFO}\n"), None,
         "graph has 2 connected components (keys 0-1 and keys 2-3); an initializer needs one"),
    Case("isolated_vertex", insert(4, "VERTEX_SE2 3 3 0 0"), None,
         "graph has 2 connected components (keys 0-2 and keys 3); an initializer needs one"),
    Case("disconnected_edge_only", raw(EDGE_ONLY_DISCONNECTED), None,
         "graph has 2 connected components (keys 0-1 and keys 2-3); an initializer needs one"),
    # not a g2o text file
    Case("directory", directory, None, "is a directory, not a g2o file"),
    Case("missing_file", missing, None, "no such file"),
    Case("binary_nul", raw(b"\x7fELF\x02\x01\x01\x00\x00\x00\x00"), 1,
         "binary data, not a g2o text file"),
    Case("binary_nul_later_line", raw(BASE.encode() + b"\x00\x00\x00\n"), 7,
         "binary data, not a g2o text file"),
    Case("invalid_utf8", raw(BASE.encode() + b"\xff\xfe garbage\n"), 7,
         "not UTF-8 text (binary file?)"),
]

assert len({case.id for case in CASES}) == len(CASES)


def _params(cases: list[Case]) -> list:
    return [pytest.param(case, id=case.id) for case in cases]


def _message(path: Path, case: Case) -> str:
    where = str(path) if case.line is None else f"{path}:{case.line}"
    return f"{where}: {case.reason}"


def _snapshot(path: Path) -> bytes | None:
    return path.read_bytes() if path.is_file() else None


# --------------------------------------------------------------------------- API


@pytest.mark.parametrize("case", _params(CASES))
def test_read_g2o_rejects(tmp_path, case):
    path = case.build(tmp_path)
    before = _snapshot(path)
    with pytest.raises(G2oFormatError) as excinfo:
        read_g2o(path)
    error = excinfo.value
    assert str(error) == _message(path, case)
    assert "\n" not in str(error)
    assert (error.path, error.line, error.reason) == (str(path), case.line, case.reason)
    assert _snapshot(path) == before


# --------------------------------------------------------------------------- CLI
# The table runs in full through the API above; each command shows once that a reader error
# becomes "Error: <message>", exit 1, with nothing written.


def test_compare_reports_a_reader_error_and_writes_no_json(tmp_path):
    case = next(c for c in CASES if c.id == "edge_nine_numbers")
    path, json_path = case.build(tmp_path), tmp_path / "out.json"
    result = CliRunner().invoke(main, [str(path), "--methods", "odometry", "--json",
                                       str(json_path)])
    cli_error(result, _message(path, case))
    assert not json_path.exists()


def test_init_reports_a_reader_error_on_one_escaped_line(tmp_path):
    """A line break in the file name is escaped: the message stays one line."""
    path, output = tmp_path / "bad\nname.g2o", tmp_path / "out.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\n")
    result = CliRunner().invoke(init_main, [str(path), "-o", str(output)])
    cli_error(result, str(path).replace("\n", "\\n") + ": holds no EDGE_SE2 line: "
              "a pose graph needs edges")
    assert not output.exists()


def test_the_console_script_reports_a_reader_error(tmp_path):
    """The installed rlpgo-compare, as a real process: no traceback, exit 1, one line."""
    search = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    script = shutil.which("rlpgo-compare", path=search)
    assert script is not None, "console script rlpgo-compare not installed"
    case = next(c for c in CASES if c.id == "truncated_last_line")
    path, json_path = case.build(tmp_path), tmp_path / "out.json"
    completed = subprocess.run([script, str(path), "--methods", "odometry", "--json",
                                str(json_path)], capture_output=True, text=True, timeout=120,
                               cwd=tmp_path)
    assert (completed.returncode, completed.stdout) == (1, "")
    assert completed.stderr == f"Error: {_message(path, case)}\n"
    assert not json_path.exists()


# --------------------------------------------------------------------------- accepted files


def _poses(values: gtsam.Values) -> dict[int, tuple[float, float, float]]:
    return {key: (values.atPose2(key).x(), values.atPose2(key).y(), values.atPose2(key).theta())
            for key in values.keys()}


@pytest.mark.parametrize("text", [
    "# written by hand\n\n" + "\n".join(BASE_LINES[:3]) + "\n   \n# edges:\n#\n\t\n"
    + "\n".join(BASE_LINES[3:]) + "\n\n# end\n",
    BASE.replace("\n", "\r\n"),
], ids=["comments_and_blank_lines", "crlf"])
def test_a_variant_of_base_reads_as_base(tmp_path, text):
    graph, values = read_g2o(raw(text)(tmp_path))
    (tmp_path / "base").mkdir()
    base_graph, base_values = read_g2o(raw(BASE)(tmp_path / "base"))
    assert _poses(values) == _poses(base_values)
    assert_same_factors(base_graph, graph)


def test_non_contiguous_ids(tmp_path):
    text = (f"VERTEX_SE2 10 0 0 0\nVERTEX_SE2 20 1 0 0\nVERTEX_SE2 35 2 0 0\n"
            f"EDGE_SE2 10 20 1 0 0 {INFO}\nEDGE_SE2 20 35 1 0 0 {INFO}\n")
    graph, values = read_g2o(raw(text)(tmp_path))
    assert sorted(values.keys()) == [10, 20, 35]
    assert _poses(values)[35] == (2.0, 0.0, 0.0)
    assert [row[1] for row in factor_rows(graph)] == [(10, 20), (20, 35)]


def test_fix_line_becomes_a_constrained_prior(tmp_path):
    graph, values = read_g2o(raw(BASE + "FIX 0 2\n")(tmp_path))
    rows = factor_rows(graph)
    assert [row[:2] for row in rows[-2:]] == [("prior", (0,)), ("prior", (2,))]
    for index, key in ((graph.size() - 2, 0), (graph.size() - 1, 2)):
        prior = graph.at(index)
        assert prior.prior().equals(values.atPose2(key), 0.0)
        assert isinstance(prior.noiseModel(), gtsam.noiseModel.Constrained)
    assert values.size() == 3


def test_edge_only_file_chains_odometry(tmp_path):
    m01, m12, m02 = (1.0, 0.5, 0.3), (0.7, -0.2, -0.4), (5.0, 5.0, 1.0)  # loop closure is off
    text = "".join(f"EDGE_SE2 {i} {j} {x!r} {y!r} {t!r} {INFO}\n"
                   for (i, j), (x, y, t) in (((0, 1), m01), ((1, 2), m12), ((0, 2), m02)))
    graph, values = read_g2o(raw(text)(tmp_path))
    assert sorted(values.keys()) == [0, 1, 2]
    assert values.atPose2(0).equals(gtsam.Pose2(), 0.0)
    assert values.atPose2(1).equals(gtsam.Pose2(*m01), 1e-12)
    expected = gtsam.Pose2(*m01).compose(gtsam.Pose2(*m12))
    assert values.atPose2(2).equals(expected, 1e-12)
    assert graph.size() == 3


@pytest.mark.parametrize("upper, information", [
    ("2 0.3 0.1 1.5 -0.2 3", [[2.0, 0.3, 0.1], [0.3, 1.5, -0.2], [0.1, -0.2, 3.0]]),
    ("1e-04 0 0 10000 0 1", [[1e-4, 0, 0], [0, 1e4, 0], [0, 0, 1]]),
], ids=["correlated", "unbalanced_up_to_the_usable_condition"])
def test_the_information_matrix_is_kept(tmp_path, upper, information):
    graph, _ = read_g2o(replace(4, f"EDGE_SE2 0 1 1 0 0 {upper}")(tmp_path))
    factor = graph.at(0)
    assert isinstance(factor, gtsam.BetweenFactorPose2)
    np.testing.assert_allclose(factor.noiseModel().information(), information, rtol=1e-12,
                               atol=0)


# --------------------------------------------------------------------------- the writer


def test_write_g2o_refuses_a_factor_whose_key_has_no_value(tmp_path):
    graph, values = read_g2o(raw(BASE)(tmp_path))
    values.erase(2)
    with pytest.raises(OutputError, match="refers to key 2, which has no value"):
        write_g2o(tmp_path / "out.g2o", graph, values)
    assert not (tmp_path / "out.g2o").exists()
