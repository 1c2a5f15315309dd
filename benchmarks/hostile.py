"""A hostile round: malformed and adversarial inputs run through the console scripts as a user
runs them, process to process, each checked against the error rules of
``../shared/CONVENTIONS.md`` (one ``Error:`` line naming the file:line, factor or keys; a
non-zero exit; no traceback; no file lost; all outputs or none; bounded memory).

    python benchmarks/hostile.py [--only REGEX] [--keep] [--list] [--name hostile]

Every input is made here, in a temporary folder, from text written by this script, from
``rlpgo-generate`` and from GTSAM's example files (``rlpgo-example NAME``), each case in a
folder of its own that is also the command's working directory. A case runs one command
(``rlpgo-init``, ``rlpgo-compare``, ``rlpgo-generate``, ``rlpgo-example``) with a time
limit of 60 s; a few send SIGINT or SIGTERM after a delay. For each case the record holds
the command, its exit status (negative: the signal that ended it), the wall seconds, the
peak resident set (``ru_maxrss`` of ``wait4``: the child's, with this process's own
footprint as its floor, measured by ``true``), the input's size, and what the checks found.

A case fails when:

- stdout or stderr holds a Python traceback, or internal text: an exception class name
  (``ValueError``, ``KeyError``, ...), ``map::at``, ``pybind``, ``Eigen``, ``std::``, a
  Python warning's ``file.py:N: ...Warning`` form, or "exactly singular" / "Indeterminant"
  without a location;
- it died by a signal (a negative status, or 134, 137, 139) other than the one the case sent;
- it ran past the time limit; or, sent SIGINT or SIGTERM, it exited 0 (the signal ignored)
  or ended more than 10 s after the signal;
- its peak exceeds 20 x the input's size, with a floor (Python + GTSAM + torch's own
  footprint: the larger of 300 MB and 1.25 x the peak of the same command on a 6-pose graph);
- a file that existed before the run changed or went (``--overwrite`` cases name the files
  they may replace), or a ``.rlpgo-*.tmp`` file is left, or any new file is left after a
  failed run (all outputs or none);
- it exited 0 without writing every output it was given, or wrote NaN or inf into one;
- it exited non-zero without exactly one ``Error:`` line on stderr, or that line does not
  name the location (a regular expression per case) where one is knowable: the line of a
  malformed line (or the keys of the factor it became), the keys of a graph-level defect.

Outcomes that differ from the case's expectation (an input this script expected to be
refused was accepted, or the reverse) are listed, but are not failures: several are
judgement calls (a NaN-free 1e300, a fullwidth digit).

Writes ``benchmarks/results/<name>.json`` (one record per case) and ``<name>.md`` (per class:
cases, failures, surprises; then each failing case with its command, exit status, the
offending lines and memory).
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import io
import json
import math
import os
import pickle
import re
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
BIN = Path(sys.executable).parent
TIME_LIMIT_S = 60.0
STOP_LIMIT_S = 10.0  # an interrupted command must end within this many seconds of the signal
MEMORY_FACTOR = 20  # a peak above this many times the input's size fails the case...
FLOOR_MB = 300.0  # ...unless it is below this floor (or the measured one, if larger)
COMMANDS = ("rlpgo-init", "rlpgo-compare", "rlpgo-generate", "rlpgo-example")
OUTPUT_SCAN_BYTES = 64 << 20  # NaN/inf scan of written outputs: this much of each, in chunks

Arg = str | bytes

# --- checks ----------------------------------------------------------------------------------

TRACEBACK = "Traceback (most recent call last)"
INTERNAL = re.compile(
    r"\b(RuntimeError|ValueError|KeyError|IndexError|TypeError|AttributeError|NameError|"
    r"ZeroDivisionError|OverflowError|AssertionError|BadZipFile|UnicodeDecodeError|"
    r"UnpicklingError|MemoryError|RecursionError|LinAlgError|NotImplementedError)\b"
    r"|map::at|pybind|\bEigen\b|Eigen::|std::|Segmentation fault|core dumped"
    r"|\.py:\d+: \w*Warning")
SINGULAR = re.compile(r"exactly singular|Indeterminant", re.IGNORECASE)
LOCATED = re.compile(r"\S:\d+\b|line \d+|factor \d+|\bkeys?\b|variable|\b[A-Za-z]?\d+\b")
NON_FINITE = re.compile(rb"(?<![A-Za-z_])(?:[+-]?nan|[+-]?inf(?:inity)?)(?![A-Za-z_])",
                        re.IGNORECASE)
SIGNAL_CODES = (134, 137, 139)


FACTOR = r"(?:\bkeys? \S+|factor \S+-\S+)"  # CONVENTIONS.md: "naming file:line or factor and keys"


def at(*lines: int) -> str:
    """The location regex of an error on one of ``lines`` (1-based): ``file:L``, ``line L``,
    or the factor's keys."""
    numbers = "|".join(str(line) for line in lines)
    return rf"(?::({numbers})\b|line ({numbers})\b|{FACTOR})"


ANY_LINE = rf"(?::\d+\b|line \d+\b|{FACTOR})"
KEYS = r"\d"  # a graph-level error names at least one key or count


# --- cases -----------------------------------------------------------------------------------

@dataclass
class Case:
    """One command on one hostile input.

    Attributes:
        cls: the class of the case (the table's rows).
        name: what is hostile about it, in a few words.
        argv: the command: a console script name, then its arguments (bytes for names that
            are not UTF-8); relative paths are in the case's folder.
        files: files written into the folder before the run, by name.
        outputs: the files the command was asked to write (relative: checked to exist after
            a run that exited 0, NaN/inf-free; absolute ones, /dev/..., are not checked).
        expect: "error", "ok" or "any": what this script expects (a mismatch is a surprise,
            not a failure).
        where: a regex the ``Error:`` line must match when the run fails (None: no location
            is knowable beyond the message itself).
        setup: run on the folder after the files are written (links, folders, generated
            graphs).
        may_change: pre-existing files the command may replace (``--overwrite``).
        interrupt: (signal, seconds): sent to the command after that delay.
        work_bytes: the size the command's memory may scale with where it has no input
            file (``rlpgo-generate``: the size of what it was asked to write); None: the
            size of the files in the folder.
        line: the hostile line (1-based), where one line was changed: an error told at
            another line is a surprise.
    """

    cls: str
    name: str
    argv: list[Arg]
    files: dict[Arg, bytes] = field(default_factory=dict)
    outputs: list[Arg] = field(default_factory=list)
    expect: str = "error"
    where: str | None = None
    setup: Callable[[Path], None] | None = None
    may_change: list[Arg] = field(default_factory=list)
    interrupt: tuple[int, float] | None = None
    work_bytes: int | None = None
    line: int | None = None


def _f(value: float) -> str:
    return f"{value:.12g}"


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


def upper(diagonal: Sequence[float]) -> str:
    """The upper triangle, row by row, of the diagonal matrix ``diagonal``."""
    size = len(diagonal)
    return " ".join(_f(diagonal[i]) if i == j else "0"
                    for i in range(size) for j in range(i, size))


INFO2 = upper([100, 100, 400])
INFO3 = upper([100, 100, 100, 400, 400, 400])
INFO_XY = upper([100, 100])
INFO_XYZ = upper([100, 100, 100])


def _poses(n: int, radius: float = 5.0) -> list[tuple[float, float, float, float]]:
    """(x, y, z, yaw) of ``n`` poses on a circle, facing along it."""
    return [(radius * math.cos(2 * math.pi * i / n), radius * math.sin(2 * math.pi * i / n),
             0.3 * math.sin(i), _wrap(2 * math.pi * i / n + math.pi / 2)) for i in range(n)]


def _local(pose, point) -> tuple[float, float, float]:
    """``point`` (x, y, z) in the frame of ``pose`` (x, y, z, yaw)."""
    c, s = math.cos(pose[3]), math.sin(pose[3])
    dx, dy, dz = point[0] - pose[0], point[1] - pose[1], point[2] - pose[2]
    return c * dx + s * dy, -s * dx + c * dy, dz


def _quat(yaw: float) -> str:
    return f"0 0 {_f(math.sin(yaw / 2))} {_f(math.cos(yaw / 2))}"


def se2_lines(n: int = 6, ids: Sequence[int] | None = None, loop: bool = True,
              info: str = INFO2, vertices: bool = True, scale: float = 1.0) -> list[str]:
    """A planar loop of ``n`` poses (ids ``ids``), its vertex lines and its EDGE_SE2 lines."""
    ids = list(ids) if ids is not None else list(range(n))
    poses = [(x * scale, y * scale, 0.0, t) for x, y, _, t in _poses(n)]
    lines = [f"VERTEX_SE2 {ids[i]} {_f(p[0])} {_f(p[1])} {_f(p[3])}"
             for i, p in enumerate(poses)] if vertices else []
    pairs = [(i, i + 1) for i in range(n - 1)] + ([(n - 1, 0)] if loop and n > 2 else [])
    for i, j in pairs:
        dx, dy, _ = _local(poses[i], poses[j])
        lines.append(f"EDGE_SE2 {ids[i]} {ids[j]} {_f(dx)} {_f(dy)} "
                     f"{_f(_wrap(poses[j][3] - poses[i][3]))} {info}")
    return lines


def se3_lines(n: int = 6, ids: Sequence[int] | None = None, loop: bool = True,
              info: str = INFO3, vertices: bool = True, scale: float = 1.0) -> list[str]:
    """A 3D loop of ``n`` poses: VERTEX_SE3:QUAT and EDGE_SE3:QUAT lines."""
    ids = list(ids) if ids is not None else list(range(n))
    poses = [(x * scale, y * scale, z * scale, t) for x, y, z, t in _poses(n)]
    lines = [f"VERTEX_SE3:QUAT {ids[i]} {_f(p[0])} {_f(p[1])} {_f(p[2])} {_quat(p[3])}"
             for i, p in enumerate(poses)] if vertices else []
    pairs = [(i, i + 1) for i in range(n - 1)] + ([(n - 1, 0)] if loop and n > 2 else [])
    for i, j in pairs:
        dx, dy, dz = _local(poses[i], poses[j])
        lines.append(f"EDGE_SE3:QUAT {ids[i]} {ids[j]} {_f(dx)} {_f(dy)} {_f(dz)} "
                     f"{_quat(_wrap(poses[j][3] - poses[i][3]))} {info}")
    return lines


LANDMARKS = [(9.0, 2.0, 1.5), (-8.0, 5.0, 2.0), (1.0, -9.0, 1.0), (6.0, 7.0, 0.5)]


def lm2_lines() -> list[str]:
    """4 poses in a loop seeing 4 points by every planar landmark tag; landmark ids repeat
    pose ids (their keys are l<id>)."""
    poses = [(x, y, 0.0, t) for x, y, _, t in _poses(4)]
    lines = se2_lines(4)
    lines += [f"VERTEX_XY {j} {_f(p[0])} {_f(p[1])}" for j, p in enumerate(LANDMARKS)]
    flat = [(p[0], p[1], 0.0) for p in LANDMARKS]
    for i, j in ((0, 0), (1, 0)):
        dx, dy, _ = _local(poses[i], flat[j])
        lines.append(f"EDGE_SE2_XY {i} {j} {_f(dx)} {_f(dy)} {INFO_XY}")
    for i, j in ((1, 1), (2, 1)):
        dx, dy, _ = _local(poses[i], flat[j])
        lines.append(f"LANDMARK2 {i} {j} {_f(dx)} {_f(dy)} {INFO_XY}")
    for i, j in ((2, 2), (3, 2)):
        dx, dy, _ = _local(poses[i], flat[j])
        lines.append(f"BR {i} {j} {_f(math.atan2(dy, dx))} {_f(math.hypot(dx, dy))} 0.05 0.1")
    for i, j in ((3, 3), (0, 3)):
        dx, dy, _ = _local(poses[i], flat[j])
        lines.append(f"LANDMARK {i} {j} {_f(dx)} {_f(dy)} 0.01 0 0.01")
    return lines


OFFSET1 = (0.1, 0.0, 0.2)


def lm3_lines() -> list[str]:
    """4 poses in 3D seeing 3 points through two sensors (identity and a shifted one)."""
    poses = _poses(4)
    lines = se3_lines(4)
    lines += ["PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1",
              f"PARAMS_SE3OFFSET 1 {' '.join(_f(v) for v in OFFSET1)} 0 0 0 1"]
    lines += [f"VERTEX_TRACKXYZ {j} {_f(p[0])} {_f(p[1])} {_f(p[2])}"
              for j, p in enumerate(LANDMARKS[:3])]
    for i, j, k in ((0, 0, 0), (1, 0, 0), (1, 1, 1), (2, 1, 1), (2, 2, 0), (3, 2, 0),
                    (3, 0, 1)):
        x, y, z = _local(poses[i], LANDMARKS[j])
        if k == 1:
            x, y, z = x - OFFSET1[0], y - OFFSET1[1], z - OFFSET1[2]
        lines.append(f"EDGE_SE3_TRACKXYZ {i} {j} {k} {_f(x)} {_f(y)} {_f(z)} {INFO_XYZ}")
    return lines


BASES: dict[str, Callable[[], list[str]]] = {
    "se2": se2_lines, "se3": se3_lines, "lm2": lm2_lines, "lm3": lm3_lines,
    "se2fix": lambda: [*se2_lines(), "FIX 0"],
}


def text(lines: Sequence[str], newline: str = "\n") -> bytes:
    return (newline.join(lines) + newline).encode("utf-8")


def nth(lines: Sequence[str], tag: str, occurrence: int = 0) -> int:
    """The index of the ``occurrence``-th line whose tag is ``tag``."""
    found = [k for k, line in enumerate(lines) if line.split()[0] == tag]
    return found[occurrence]


def with_line(lines: Sequence[str], index: int, new: str) -> list[str]:
    out = list(lines)
    out[index] = new
    return out


def set_field(lines: Sequence[str], tag: str, position: int, value: str,
              occurrence: int = 0) -> tuple[list[str], int]:
    """``lines`` with field ``position`` (0: the tag) of a ``tag`` line set to ``value``;
    and that line's number (1-based)."""
    index = nth(lines, tag, occurrence)
    fields = lines[index].split()
    fields[position] = value
    return with_line(lines, index, " ".join(fields)), index + 1


def init(name: Arg = "in.g2o", out: Arg = "out.g2o", *options: Arg) -> list[Arg]:
    return ["rlpgo-init", name, "-o", out, *options]


def g2o_case(cls: str, name: str, lines: Sequence[str], *, expect: str = "error",
             where: str | None = None, options: Sequence[Arg] = (), file: str = "in.g2o",
             out: str = "out.g2o") -> Case:
    return Case(cls, name, init(file, out, *options), {file: text(lines)}, [out], expect,
                where)


# --- class: malformed lines of every tag ----------------------------------------------------

# tag: (base file, id fields after the tag)
TAGS = {
    "VERTEX_SE2": ("se2", 1), "EDGE_SE2": ("se2", 2), "VERTEX_SE3:QUAT": ("se3", 1),
    "EDGE_SE3:QUAT": ("se3", 2), "FIX": ("se2fix", 1), "VERTEX_XY": ("lm2", 1),
    "EDGE_SE2_XY": ("lm2", 2), "VERTEX_TRACKXYZ": ("lm3", 1), "EDGE_SE3_TRACKXYZ": ("lm3", 3),
    "PARAMS_SE3OFFSET": ("lm3", 1), "BR": ("lm2", 2), "LANDMARK": ("lm2", 2),
    "LANDMARK2": ("lm2", 2),
}


def _mutations(fields: list[str], ids: int) -> list[tuple[str, list[str], str, bool]]:
    """(name, new fields, expectation, whether the error's line is knowable) of each
    mutation of one line's fields."""
    first = min(ids + 1, len(fields) - 1)  # the first number after the ids (FIX: its id)

    def put(position: int, value: str) -> list[str]:
        out = list(fields)
        out[position] = value
        return out

    fix = fields[0] == "FIX"
    return [
        ("one field too few", fields[:-1], "error", True),
        ("one field too many", [*fields, "1"], "ok" if fix else "error", True),
        ("nan", put(first, "nan"), "error", True),
        ("inf in the last field", put(len(fields) - 1, "inf"), "error", True),
        ("1e300", put(first, "1e300"), "any", True),
        ("negative zero", put(first, "-0.0"), "any" if fix else "ok", True),
        ("hex float", put(first, "0x1p-2"), "error", True),
        ("fullwidth digits", put(first, "\uff11.\uff15"), "any", True),
        ("arabic-indic digit as id", put(1, "\u0663"), "any", True),
        ("fractional id", put(1, fields[1] + ".5"), "error", True),
        ("a word for a number", put(first, "one"), "error", True),
    ]


def malformed_cases() -> list[Case]:
    cases = []
    for tag, (base, ids) in TAGS.items():
        lines = BASES[base]()
        index = nth(lines, tag)
        for name, fields, expect, _ in _mutations(lines[index].split(), ids):
            changed = with_line(lines, index, " ".join(fields))
            where = at(index + 1) if expect != "ok" else ANY_LINE
            if "digit" in name or name == "1e300":  # a duplicate id, or an overflow, may be
                where = ANY_LINE  # told at another line (where the value is used)
            cases.append(g2o_case("g2o line", f"{tag}: {name}", changed, expect=expect,
                                  where=where))
            cases[-1].line = index + 1
    return cases


# --- class: g2o semantics (ids, information, quaternions, ranges, offsets) -------------------

def semantic_cases() -> list[Case]:
    cls = "g2o semantics"
    cases = []
    se2, se3, lm2, lm3 = se2_lines(), se3_lines(), lm2_lines(), lm3_lines()

    def add(name: str, lines: Sequence[str], expect: str = "error",
            where: str | None = ANY_LINE, options: Sequence[Arg] = ()) -> None:
        cases.append(g2o_case(cls, name, lines, expect=expect, where=where, options=options))

    def dup(name: str, lines: list[str], tag: str, new: str) -> None:
        first = nth(lines, tag) + 1
        add(name, [*lines, new], where=at(first, len(lines) + 1))

    dup("VERTEX_SE2 id twice", se2, "VERTEX_SE2", "VERTEX_SE2 0 1 1 0")
    dup("VERTEX_SE3:QUAT id twice", se3, "VERTEX_SE3:QUAT", "VERTEX_SE3:QUAT 0 1 1 0 0 0 0 1")
    dup("VERTEX_XY id twice", lm2, "VERTEX_XY", "VERTEX_XY 0 1 1")
    dup("VERTEX_TRACKXYZ id twice", lm3, "VERTEX_TRACKXYZ", "VERTEX_TRACKXYZ 0 1 1 1")
    dup("PARAMS_SE3OFFSET id twice", lm3, "PARAMS_SE3OFFSET",
        "PARAMS_SE3OFFSET 0 1 0 0 0 0 0 1")
    add("EDGE_SE2 self-loop", [*se2, f"EDGE_SE2 2 2 0 0 0 {INFO2}"], where=at(len(se2) + 1))
    add("EDGE_SE3:QUAT self-loop", [*se3, f"EDGE_SE3:QUAT 2 2 0 0 0 0 0 0 1 {INFO3}"],
        where=at(len(se3) + 1))
    add("EDGE_SE2 repeated identically", [*se2, se2[-1]], expect="ok")
    for label, ids, expect in (("2^63-1", [0, 1, 2, 3, 4, 2**63 - 1], "any"),
                               ("2^63 (a valid uint64 key)", [0, 1, 2, 3, 4, 2**63], "any"),
                               ("2^64+5", [0, 1, 2, 3, 4, 2**64 + 5], "error"),
                               ("negative", [-3, -2, -1, 0, 1, 2], "any"),
                               ("-2^63", [0, 1, 2, 3, 4, -(2**63)], "any")):
        add(f"pose ids {label} (2D)", se2_lines(6, ids), expect=expect)
    add("pose ids 2^63-1 (3D)", se3_lines(6, [0, 1, 2, 3, 4, 2**63 - 1]), expect="any")
    add("pose ids 2^64+5 (3D)", se3_lines(6, [0, 1, 2, 3, 4, 2**64 + 5]))
    for label, lid in (("2^56", 2**56), ("2^63", 2**63), ("-1", -1)):
        changed = [" ".join([*line.split()[:2], str(lid), *line.split()[3:]])
                   if line.split()[0] in ("EDGE_SE2_XY",) else line for line in lm2]
        changed, _ = set_field(changed, "VERTEX_XY", 1, str(lid))
        add(f"landmark id {label}", changed, expect="any")
    add("landmark ids equal to pose ids", lm2, expect="ok")
    add("landmark ids equal to pose ids, --method all", lm2, expect="ok",
        options=["--method", "all"])
    info_cases = [
        ("EDGE_SE2 zero information", se2, "EDGE_SE2", upper([0, 0, 0]), "error"),
        ("EDGE_SE2 negative information", se2, "EDGE_SE2", upper([-100, -100, -400]),
         "error"),
        ("EDGE_SE2 indefinite information", se2, "EDGE_SE2", "100 1000 0 100 0 400",
         "error"),
        ("EDGE_SE2 singular information (no rotation)", se2, "EDGE_SE2",
         upper([100, 100, 0]), "any"),
        ("EDGE_SE3:QUAT zero information", se3, "EDGE_SE3:QUAT", upper([0] * 6), "any"),
        ("EDGE_SE3:QUAT negative information", se3, "EDGE_SE3:QUAT", upper([-1] * 6),
         "any"),
        ("EDGE_SE3:QUAT indefinite information", se3, "EDGE_SE3:QUAT",
         "100 500 0 0 0 0 100 0 0 0 0 100 0 0 0 400 0 0 400 0 400", "any"),
        ("EDGE_SE2_XY zero information", lm2, "EDGE_SE2_XY", upper([0, 0]), "error"),
        ("EDGE_SE2_XY indefinite information", lm2, "EDGE_SE2_XY", "100 500 100",
         "error"),
        ("LANDMARK2 negative information", lm2, "LANDMARK2", upper([-100, -100]),
         "error"),
        ("EDGE_SE3_TRACKXYZ zero information", lm3, "EDGE_SE3_TRACKXYZ", upper([0] * 3),
         "error"),
        ("EDGE_SE3_TRACKXYZ indefinite information", lm3, "EDGE_SE3_TRACKXYZ",
         "100 500 0 100 0 100", "error"),
        ("BR zero sigmas", lm2, "BR", "0 0", "error"),
        ("BR negative sigma", lm2, "BR", "-0.05 0.1", "error"),
        ("LANDMARK zero variance", lm2, "LANDMARK", "0 0 0", "error"),
        ("LANDMARK negative variance", lm2, "LANDMARK", "-1 0 -1", "error"),
    ]
    for name, lines, tag, new, expect in info_cases:
        index = nth(lines, tag)
        fields = lines[index].split()
        numbers = new.split()
        width = len(numbers)
        fields = fields[:len(fields) - width] + numbers
        add(name, with_line(lines, index, " ".join(fields)), expect=expect,
            where=at(index + 1))
    for name, lines, tag, start in (("VERTEX_SE3:QUAT zero quaternion", se3,
                                     "VERTEX_SE3:QUAT", 5),
                                    ("EDGE_SE3:QUAT zero quaternion", se3, "EDGE_SE3:QUAT", 6),
                                    ("PARAMS_SE3OFFSET zero quaternion", lm3,
                                     "PARAMS_SE3OFFSET", 5)):
        index = nth(lines, tag)
        fields = lines[index].split()
        fields[start:start + 4] = ["0", "0", "0", "0"]
        add(name, with_line(lines, index, " ".join(fields)), where=at(index + 1))
    index = nth(se3, "EDGE_SE3:QUAT", 1)
    fields = se3[index].split()
    fields[6:10] = [_f(2 * float(v)) for v in fields[6:10]]
    add("EDGE_SE3:QUAT quaternion of norm 2", with_line(se3, index, " ".join(fields)),
        expect="ok")
    fields = se3[index].split()
    fields[6:10] = ["1e-300", "0", "0", "1e-300"]
    add("EDGE_SE3:QUAT quaternion of norm 1e-300", with_line(se3, index, " ".join(fields)),
        expect="any", where=at(index + 1))
    for name, lines, tag, first, values in (
            ("EDGE_SE2_XY at zero range", lm2, "EDGE_SE2_XY", 3, ["0", "0"]),
            ("LANDMARK2 at zero range", lm2, "LANDMARK2", 3, ["0", "0"]),
            ("BR zero range", lm2, "BR", 4, ["0"]),
            ("BR negative range", lm2, "BR", 4, ["-5"]),
            ("BR range 1e-300", lm2, "BR", 4, ["1e-300"]),
            ("LANDMARK at zero range", lm2, "LANDMARK", 3, ["0", "0"]),
            ("EDGE_SE3_TRACKXYZ at zero range", lm3, "EDGE_SE3_TRACKXYZ", 4, ["0", "0", "0"])):
        index = nth(lines, tag)
        fields = lines[index].split()
        fields[first:first + len(values)] = values
        add(name, with_line(lines, index, " ".join(fields)),
            expect="any" if "1e-300" in name else "error", where=at(index + 1))
    for label, value in (("unknown sensor id 7", "7"), ("sensor id -1", "-1")):
        changed, line = set_field(lm3, "EDGE_SE3_TRACKXYZ", 3, value)
        add(f"EDGE_SE3_TRACKXYZ {label}", changed, where=at(line))
    for name, lines, new in (
            ("EDGE_SE2 to a pose with no vertex", se2, f"EDGE_SE2 3 77 1 0 0 {INFO2}"),
            ("EDGE_SE3:QUAT to a pose with no vertex", se3,
             f"EDGE_SE3:QUAT 77 3 1 0 0 0 0 0 1 {INFO3}"),
            ("EDGE_SE2_XY from a pose with no vertex", lm2, f"EDGE_SE2_XY 77 0 1 1 {INFO_XY}"),
            ("EDGE_SE3_TRACKXYZ from a pose with no vertex", lm3,
             f"EDGE_SE3_TRACKXYZ 77 0 0 1 1 1 {INFO_XYZ}")):
        add(name, [*lines, new], where=at(len(lines) + 1))
    return cases


# --- class: graph level -----------------------------------------------------------------------

def graph_cases() -> list[Case]:
    cls = "graph"
    cases = []
    se2, se3, lm2, lm3 = se2_lines(), se3_lines(), lm2_lines(), lm3_lines()

    def add(name: str, lines: Sequence[str], expect: str = "any", where: str | None = KEYS,
            options: Sequence[Arg] = (), command: str = "rlpgo-init") -> None:
        case = g2o_case(cls, name, lines, expect=expect, where=where, options=options)
        if command == "rlpgo-compare":
            case.argv, case.outputs = ["rlpgo-compare", "in.g2o", *options], []
        cases.append(case)

    add("two components (2D)", [*se2, *se2_lines(6, range(10, 16))], expect="error")
    add("two components (3D)", [*se3, *se3_lines(6, range(10, 16))], expect="error")
    add("two components, rlpgo-compare", [*se2, *se2_lines(6, range(10, 16))],
        expect="error", command="rlpgo-compare")
    add("landmark vertex no pose sees (2D)", [*lm2, "VERTEX_XY 9 3 3"], expect="error",
        where=at(len(lm2) + 1))
    add("landmark vertex no pose sees (3D)", [*lm3, "VERTEX_TRACKXYZ 9 3 3 3"],
        expect="error", where=at(len(lm3) + 1))
    lone = _local((20.0, 0.0, 0.0, 0.0), (9.0, 2.0, 0.0))
    add("pose joined only through a landmark (2D)",
        [*lm2, "VERTEX_SE2 10 20 0 0", f"EDGE_SE2_XY 10 0 {_f(lone[0])} {_f(lone[1])} "
         f"{INFO_XY}"])
    lone3 = _local((20.0, 0.0, 0.0, 0.0), LANDMARKS[0])
    add("pose joined only through a landmark (3D)",
        [*lm3, "VERTEX_SE3:QUAT 10 20 0 0 0 0 0 1",
         f"EDGE_SE3_TRACKXYZ 10 0 0 {' '.join(_f(v) for v in lone3)} {INFO_XYZ}"])
    add("every pose FIXed (2D)", [*se2, "FIX 0 1 2 3 4 5"])
    add("every pose FIXed (3D)", [*se3, "FIX 0 1 2 3 4 5"])
    add("every pose FIXed, --method all", [*se2, "FIX 0 1 2 3 4 5"],
        options=["--method", "all"])
    add("FIX on an unknown id", [*se2, "FIX 42"], expect="error", where=at(len(se2) + 1))
    add("FIX on an id that is a pose's and a landmark's", [*lm2, "FIX 3"], expect="ok",
        where=ANY_LINE)
    add("FIX twice on one id", [*se2, "FIX 0", "FIX 0"], where=ANY_LINE)
    add("FIX on two poses the edges disagree with", [*se2, "FIX 0 3"],
        where=ANY_LINE)
    add("one pose, no edge (2D)", ["VERTEX_SE2 0 0 0 0"])
    add("one pose, no edge (3D)", ["VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1"])
    add("one pose, FIXed", ["VERTEX_SE2 0 1 2 0.3", "FIX 0"])
    add("two poses, one edge", se2_lines(2), expect="ok")
    add("parallel edges that agree", [*se2, *se2[6:]], expect="ok")
    add("parallel edges that contradict", [*se2, f"EDGE_SE2 0 1 -50 30 3 {INFO2}"],
        expect="ok")
    for dim, lines_of, size in ((2, se2_lines, 3), (3, se3_lines, 6)):
        for label, value in (("1e20", 1e20), ("1e-20", 1e-20)):
            info = upper([value] * size)
            add(f"information {label} ({dim}D)", lines_of(6, info=info))
    add("information 1e20 and 1e-20 in one edge (2D)",
        se2_lines(6, info=upper([1e20, 1e-20, 1.0])))
    add("edges of 1e25 m (2D)", se2_lines(6, scale=1e24))
    add("edges of 1e25 m (3D)", se3_lines(6, scale=1e24))
    add("edges of 1e25 m, --method all", se2_lines(6, scale=1e24),
        options=["--method", "all"])
    add("edges of 1e25 m, --robust", se2_lines(6, scale=1e24), options=["--robust"])
    add("edges of 1e-15 m (2D)", se2_lines(6, scale=1e-16))
    add("VERTEX_SE2 with EDGE_SE3:QUAT", [*se2[:6], *se3[6:]], expect="error",
        where=ANY_LINE)
    add("planar graph with a VERTEX_TRACKXYZ", [*se2, "VERTEX_TRACKXYZ 0 1 1 1"],
        expect="error", where=ANY_LINE)
    add("3D graph with an EDGE_SE2_XY", [*lm3, f"EDGE_SE2_XY 0 0 1 1 {INFO_XY}"],
        expect="error", where=ANY_LINE)
    add("edges only, no vertex (2D)", se2_lines(6, vertices=False), expect="ok")
    add("edges only, no vertex (3D)", se3_lines(6, vertices=False), expect="ok")
    add("edges only, ids 0, 5, 1000", se2_lines(3, [0, 5, 1000], vertices=False),
        expect="ok")
    add("edges only, two components", [*se2_lines(3, vertices=False),
                                       *se2_lines(3, [10, 11, 12], vertices=False)],
        expect="error")
    add("every pose and edge at identity", ["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 0 0 0",
                                            "VERTEX_SE2 2 0 0 0",
                                            f"EDGE_SE2 0 1 0 0 0 {INFO2}",
                                            f"EDGE_SE2 1 2 0 0 0 {INFO2}",
                                            f"EDGE_SE2 2 0 0 0 0 {INFO2}"], expect="ok")
    return cases


# --- class: file level ------------------------------------------------------------------------

def _write_long(path: Path, prefix: bytes, size: int, filler: bytes) -> None:
    with open(path, "wb") as stream:
        stream.write(prefix)
        chunk = filler * (1 << 20)
        left = size
        while left > 0:
            stream.write(chunk[:min(left, len(chunk))])
            left -= len(chunk)


def file_cases() -> list[Case]:
    cls = "file"
    se2, se3 = se2_lines(), se3_lines()
    body = text(se2)
    garbage = bytes((i * 1103515245 + 12345) % 256 for i in range(4096))

    def case(name: str, data: bytes | None, expect: str = "error",
             where: str | None = None, setup=None, file: str = "in.g2o") -> Case:
        files = {file: data} if data is not None else {}
        return Case(cls, name, init(file), files, ["out.g2o"], expect, where, setup)

    long_edge = se2[6] + " 1" * 60_000
    return [
        case("empty file", b""),
        case("only comments", b"# a\n# b\n#VERTEX_SE2 0 0 0 0\n"),
        case("only blank and whitespace lines", b"\n   \n\t\n\n"),
        case("CRLF line ends (2D)", text(se2, "\r\n"), "ok"),
        case("CRLF line ends (3D)", text(se3, "\r\n"), "ok"),
        case("CR-only line ends", text(se2, "\r"), "any"),
        case("tabs between fields", body.replace(b" ", b"\t"), "ok"),
        case("runs of spaces and tabs, leading blanks",
             b"".join(b"  \t " + line.replace(b" ", b" \t  ") + b"\n"
                      for line in body.splitlines()), "ok"),
        case("comment after the numbers", text([se2[0] + " # first", *se2[1:]]), "any",
             at(1)),
        case("UTF-8 byte-order mark", b"\xef\xbb\xbf" + body, "any", at(1)),
        case("no newline at the end", body.rstrip(b"\n"), "ok"),
        case("100 KB comment line", text([*se2[:3], "#" + "x" * 100_000, *se2[3:]]), "any",
             at(4)),
        case("EDGE_SE2 line with 60000 extra fields", text([*se2[:6], long_edge, *se2[7:]]),
             "error", at(7)),
        case("5 MB without a newline", None, "error", at(1),
             lambda folder: _write_long(folder / "in.g2o", b"VERTEX_SE2 0 ", 5 << 20, b"1")),
        case("binary garbage", garbage),
        case("NUL byte inside a line", text([se2[0], se2[1].replace(" ", "\0", 1), *se2[2:]]),
             "error", at(2)),
        case("Latin-1 byte in a comment", b"# caf\xe9\n" + body, "any"),
        case("Latin-1 byte in a tag", body.replace(b"EDGE_SE2", b"EDGE_SE\xb2", 1), "error",
             at(7)),
        case("UTF-16 text", "\n".join(se2).encode("utf-16")),
        case("unknown tag", text([*se2, "EDGE_FOO 0 1 2"]), "error", at(len(se2) + 1)),
        case("lowercase tag", text([se2[0].lower(), *se2[1:]]), "error", at(1)),
        case("gzip-compressed g2o", _gzip(body)),
        case("g2o text in a .pyfg file", body, "error", ANY_LINE, file="in.pyfg"),
        case("/dev/zero as input", None, "error", setup=None, file="/dev/zero"),
        case("/dev/urandom as input", None, "error", setup=None, file="/dev/urandom"),
        case("/dev/stdin (empty) as input", None, "error", setup=None, file="/dev/stdin"),
    ]


def _gzip(data: bytes) -> bytes:
    return gzip.compress(data, mtime=0)


# --- class: landmark graphs from rlpgo-generate, corrupted line by line -----------------------

def generated_cases(cache: Path) -> list[Case]:
    cls = "generated landmarks"
    cases = []
    for dim in (2, 3):
        path = cache / f"landmarks{dim}d.g2o"
        lines = path.read_text().splitlines()
        tags = sorted({line.split()[0] for line in lines if line.strip()},
                      key=lambda tag: nth(lines, tag))
        for tag in tags:
            found = [k for k, line in enumerate(lines) if line.split()[0] == tag]
            picks = sorted({found[0], found[len(found) // 2], found[-1]})
            for index in picks[:2] if len(picks) > 1 else picks:
                fields = lines[index].split()
                for name, new, where in (
                        ("truncated", fields[:-1], at(index + 1)),
                        ("nan in its last field", [*fields[:-1], "nan"], at(index + 1)),
                        ("first id 999999", [fields[0], "999999", *fields[2:]], ANY_LINE)):
                    changed = with_line(lines, index, " ".join(new))
                    expect = "any" if "999999" in name else "error"
                    cases.append(g2o_case(cls, f"{dim}D line {index + 1} {tag}: {name}",
                                          changed, expect=expect, where=where))
                    if "999999" not in name:  # a vanished id is told where it is used
                        cases[-1].line = index + 1
        cases.append(g2o_case(cls, f"{dim}D as generated", lines, expect="ok"))
        cases.append(g2o_case(cls, f"{dim}D --robust", lines, expect="any",
                              options=["--robust"]))
        cases.append(g2o_case(cls, f"{dim}D every other line dropped", lines[::2],
                              expect="any", where=ANY_LINE))
        cases.append(g2o_case(cls, f"{dim}D lines in reverse order", lines[::-1],
                              expect="any", where=ANY_LINE))
    return cases


# --- class: PyFG ------------------------------------------------------------------------------

def pyfg_cases(goats: Path) -> list[Case]:
    cls = "pyfg"
    lines = goats.read_text().splitlines()

    def case(name: str, changed: Sequence[str], expect: str = "error",
             where: str | None = ANY_LINE, out: str = "out.pyfg") -> Case:
        return Case(cls, name, init("in.pyfg", out), {"in.pyfg": text(changed)}, [out],
                    expect, where)

    vertex = nth(lines, "VERTEX_SE2", 5)
    edge = nth(lines, "EDGE_SE2", 3)
    ranged = nth(lines, "EDGE_RANGE", 7)
    point = nth(lines, "VERTEX_XY")
    cases = [
        case("goats_15 as shipped", lines, "ok"),
        case("goats_15 written as g2o (ranges have no g2o line)", lines, "any", where=None,
             out="out.g2o"),
        case("empty .pyfg", [], where=None),
        case("only a comment", ["# nothing"], where=None),
    ]
    edits = [
        ("VERTEX_SE2 one field too few", vertex, lines[vertex].rsplit(" ", 1)[0]),
        ("VERTEX_SE2 nan theta", vertex, lines[vertex].rsplit(" ", 1)[0] + " nan"),
        ("VERTEX_SE2 name A012", vertex, lines[vertex].replace(" A5 ", " A012 ")),
        ("VERTEX_SE2 name 5 (no letter)", vertex, lines[vertex].replace(" A5 ", " 5 ")),
        ("VERTEX_SE2 name index 2^56", vertex,
         lines[vertex].replace(" A5 ", f" A{2**56} ")),
        ("VERTEX_SE2 nan timestamp", vertex, lines[vertex].replace("0.000000000", "nan", 1)),
        ("VERTEX_XY with a timestamp", point, lines[point].replace("VERTEX_XY ",
                                                                   "VERTEX_XY 0.0 ")),
        ("EDGE_SE2 to an unknown name", edge, lines[edge].replace(" A4 ", " A9999 ")),
        ("EDGE_SE2 self-loop", edge, lines[edge].replace(" A4 ", " A3 ")),
        ("EDGE_SE2 covariance not positive definite", edge,
         " ".join(lines[edge].split()[:7] + ["1", "5", "0", "1", "0", "1"])),
        ("EDGE_SE2 zero covariance", edge,
         " ".join(lines[edge].split()[:7] + ["0"] * 6)),
        ("EDGE_SE2 joining a pose and a landmark", edge, lines[edge].replace(" A4 ", " L0 ")),
        ("EDGE_RANGE negative range", ranged,
         " ".join([*lines[ranged].split()[:4], "-3", "0.5"])),
        ("EDGE_RANGE zero variance", ranged, " ".join([*lines[ranged].split()[:5], "0"])),
        ("EDGE_RANGE inf range", ranged, " ".join([*lines[ranged].split()[:4], "inf",
                                                   "0.5"])),
        ("EDGE_RANGE between one name", ranged,
         " ".join([*lines[ranged].split()[:2], "L0", "L0", *lines[ranged].split()[4:]])),
        ("a VERTEX_SE3:QUAT line", vertex, "VERTEX_SE3:QUAT 0.0 A5 0 0 0 0 0 0 1"),
        ("a g2o EDGE_SE2 line (no timestamp)", edge, " ".join(
            ["EDGE_SE2", "4", "5", *lines[edge].split()[4:]])),
    ]
    for name, index, new in edits:
        cases.append(case(name, with_line(lines, index, new), where=at(index + 1)))
    cases.append(case("VERTEX_SE2 defined twice", [*lines, lines[vertex]],
                      where=at(vertex + 1, len(lines) + 1)))
    cases.append(case("a pose no factor names", [*lines, "VERTEX_SE2 0.0 B7 1 1 0"],
                      where=at(len(lines) + 1)))
    cases.append(case("landmark L0's vertex removed", lines[:point] + lines[point + 1:],
                      where=ANY_LINE))
    cases.append(case("CRLF line ends", lines, "ok"))
    cases[-1].files["in.pyfg"] = text(lines, "\r\n")
    cases.append(case("only the EDGE_RANGE lines and their vertices",
                      [line for line in lines if not line.startswith("EDGE_SE2")], "any",
                      where=KEYS))
    three_d = se3_lines()
    cases.append(Case(cls, "3D g2o graph written as .pyfg", init("in.g2o", "out.pyfg"),
                      {"in.g2o": text(three_d)}, ["out.pyfg"], "error", None))
    cases.append(Case(cls, "goats_15, rlpgo-compare", ["rlpgo-compare", "in.pyfg"],
                      {"in.pyfg": text(lines)}, [], "any", None))
    return cases


# --- class: command line ----------------------------------------------------------------------

def _link(target: str, name: str) -> Callable[[Path], None]:
    return lambda folder: os.symlink(target, folder / name)


def _hardlink(target: str, name: str) -> Callable[[Path], None]:
    return lambda folder: os.link(folder / target, folder / name)


def _mkdir(name: str) -> Callable[[Path], None]:
    return lambda folder: (folder / name).mkdir()


def command_cases(lm2: bytes, lm3: bytes, pose3: bytes) -> list[Case]:
    cls = "command line"
    body = text(se2_lines())
    ins = {"in.g2o": body}
    out = ["out.g2o"]
    cases = [
        Case(cls, "output is the input", init("in.g2o", "in.g2o"), ins),
        Case(cls, "output is the input, --overwrite", init("in.g2o", "in.g2o", "--overwrite"),
             ins),
        Case(cls, "output is ./the input, --overwrite",
             init("in.g2o", "./in.g2o", "--overwrite"), ins),
        Case(cls, "output is sub/../the input, --overwrite",
             init("in.g2o", "sub/../in.g2o", "--overwrite"), ins, setup=_mkdir("sub")),
        Case(cls, "output is a symlink to the input, --overwrite",
             init("in.g2o", "link.g2o", "--overwrite"), ins, setup=_link("in.g2o", "link.g2o")),
        Case(cls, "output is a hard link to the input, --overwrite",
             init("in.g2o", "hard.g2o", "--overwrite"), ins,
             setup=_hardlink("in.g2o", "hard.g2o")),
        Case(cls, "--json is the input, --overwrite",
             init("in.g2o", "out.g2o", "--json", "in.g2o", "--overwrite"), ins),
        Case(cls, "--json is the output", init("in.g2o", "out.g2o", "--json", "out.g2o"), ins),
        Case(cls, "--outliers-out is the input, --robust --overwrite",
             init("in.g2o", "out.g2o", "--robust", "--outliers-out", "in.g2o",
                  "--overwrite"), ins),
        Case(cls, "--outliers-out is the output, --robust",
             init("in.g2o", "out.g2o", "--robust", "--outliers-out", "out.g2o"), ins),
        Case(cls, "output in a missing folder", init("in.g2o", "missing/out.g2o"), ins,
             where="missing"),
        Case(cls, "--json in a missing folder (output must not be left)",
             init("in.g2o", "out.g2o", "--json", "missing/run.json"), ins, out,
             where="missing"),
        Case(cls, "output /dev/full", init("in.g2o", "/dev/full"), ins, where="/dev/full"),
        Case(cls, "--json /dev/full (output must not be left)",
             init("in.g2o", "out.g2o", "--json", "/dev/full"), ins, out, where="/dev/full"),
        Case(cls, "output /dev/null", init("in.g2o", "/dev/null"), ins, ["/dev/null"], "ok"),
        Case(cls, "output exists, no --overwrite", init(), {**ins, "out.g2o": b"keep me\n"},
             where="out.g2o"),
        Case(cls, "--json exists, no --overwrite (output must not be left)",
             init("in.g2o", "out.g2o", "--json", "run.json"), {**ins, "run.json": b"{}\n"},
             out, where="run.json"),
        Case(cls, "output exists, --overwrite", init("in.g2o", "out.g2o", "--overwrite"),
             {**ins, "out.g2o": b"old\n"}, out, "ok", may_change=["out.g2o"]),
        Case(cls, "output is a symlink to another file, --overwrite",
             init("in.g2o", "link.g2o", "--overwrite"), {**ins, "other.g2o": b"other\n"},
             ["link.g2o"], "any", setup=_link("other.g2o", "link.g2o"),
             may_change=["link.g2o", "other.g2o"]),
        Case(cls, "output is a dangling symlink", init("in.g2o", "link.g2o"), ins,
             ["link.g2o"], "any", setup=_link("nowhere/x.g2o", "link.g2o"),
             may_change=["link.g2o"]),
        Case(cls, "output is an existing folder", init("in.g2o", "sub"), ins, where="sub",
             setup=_mkdir("sub")),
        Case(cls, "output is an empty name", init("in.g2o", ""), ins),
        Case(cls, "output name of 300 bytes", init("in.g2o", "o" * 296 + ".g2o"), ins),
        Case(cls, "input name with spaces", init("my graph.g2o", "my out.g2o"),
             {"my graph.g2o": body}, ["my out.g2o"], "ok"),
        Case(cls, "input name with a newline", init("a\nb.g2o", "o\nut.g2o"),
             {"a\nb.g2o": body}, ["o\nut.g2o"], "ok"),
        Case(cls, "input name not UTF-8", init(b"in\xff.g2o", b"out\xfe.g2o"),
             {b"in\xff.g2o": body}, [b"out\xfe.g2o"], "ok"),
        Case(cls, "malformed input, name not UTF-8", init(b"in\xff.g2o", "out.g2o"),
             {b"in\xff.g2o": body + b"EDGE_SE2 0 1\n"}, out, where=at(13)),
        Case(cls, "malformed input, name with a newline", init("a\nb.g2o", "out.g2o"),
             {"a\nb.g2o": body + b"EDGE_SE2 0 1\n"}, out, where=at(13)),
        Case(cls, "input name starting with a dash", init("-in.g2o", "out.g2o"),
             {"-in.g2o": body}, out, "any"),
        Case(cls, "unicode input name", init("gr\u00e4ph\u2713.g2o", "\u00f6ut.g2o"),
             {"gr\u00e4ph\u2713.g2o": body}, ["\u00f6ut.g2o"], "ok"),
        Case(cls, "input name of 300 bytes", init("i" * 296 + ".g2o"), ins),
        Case(cls, "input is a symlink", init("link.g2o"), ins, out, "ok",
             setup=_link("in.g2o", "link.g2o")),
        Case(cls, "input is a dangling symlink", init("link.g2o"), {}, where="link.g2o",
             setup=_link("nowhere.g2o", "link.g2o")),
        Case(cls, "input is a folder", init(".", "out.g2o"), ins),
        Case(cls, "input is a folder named x.g2o", init("x.g2o"), {}, setup=_mkdir("x.g2o")),
        Case(cls, "input does not exist", init("nothing.g2o"), {}, where="nothing.g2o"),
        Case(cls, "--method unknown", init("in.g2o", "out.g2o", "--method", "bogus"), ins),
        Case(cls, "--method empty", init("in.g2o", "out.g2o", "--method", ""), ins),
        Case(cls, "--method rl@bogus", init("in.g2o", "out.g2o", "--method", "rl@bogus"), ins),
        Case(cls, "--method lago on a 3D graph", init("in.g2o", "out.g2o", "--method", "lago"),
             {"in.g2o": pose3}),
        Case(cls, "--method rl on a 3D graph", init("in.g2o", "out.g2o", "--method", "rl"),
             {"in.g2o": pose3}),
        Case(cls, "--iters -1", init("in.g2o", "out.g2o", "--iters", "-1"), ins),
        Case(cls, "--iters 10^12", init("in.g2o", "out.g2o", "--iters", "1000000000000"), ins),
        Case(cls, "--iters 100000", init("in.g2o", "out.g2o", "--iters", "100000"), ins, out,
             "ok"),
        Case(cls, "--budget -1", init("in.g2o", "out.g2o", "--budget", "-1"), ins),
        Case(cls, "--budget nan", init("in.g2o", "out.g2o", "--budget", "nan"), ins),
        Case(cls, "--budget 0", init("in.g2o", "out.g2o", "--budget", "0"), ins, out, "any"),
        Case(cls, "--covariance-scale 0", init("in.g2o", "out.g2o", "--robust",
                                               "--covariance-scale", "0"), ins),
        Case(cls, "--robust --refine lm", init("in.g2o", "out.g2o", "--robust", "--refine",
                                               "lm"), ins),
        Case(cls, "--robust on a planar landmark graph", init("in.g2o", "out.g2o", "--robust"),
             {"in.g2o": lm2}, out, "any"),
        Case(cls, "--robust on a 3D landmark graph", init("in.g2o", "out.g2o", "--robust"),
             {"in.g2o": lm3}, out, "any"),
        Case(cls, "--robust --outliers-out on a landmark graph",
             init("in.g2o", "out.g2o", "--robust", "--outliers-out", "rej.txt"),
             {"in.g2o": lm2}, ["out.g2o", "rej.txt"], "any"),
        Case(cls, "--outliers-out without --robust",
             init("in.g2o", "out.g2o", "--outliers-out", "rej.txt"), ins, out, "any"),
        Case(cls, "--method rl on a landmark graph",
             init("in.g2o", "out.g2o", "--method", "rl"), {"in.g2o": lm2}, out, "any"),
        Case(cls, "rlpgo-compare: no such file", ["rlpgo-compare", "nothing.g2o"], {},
             where="nothing.g2o"),
        Case(cls, "rlpgo-compare: a good file and a malformed one",
             ["rlpgo-compare", "in.g2o", "bad.g2o", "--json", "c.json"],
             {**ins, "bad.g2o": body + b"EDGE_SE2 0 1\n"}, ["c.json"], where=at(13)),
        Case(cls, "rlpgo-compare: --json /dev/full", ["rlpgo-compare", "in.g2o", "--json",
                                                     "/dev/full"], ins, where="/dev/full"),
        Case(cls, "rlpgo-compare: --json is the input, --overwrite",
             ["rlpgo-compare", "in.g2o", "--json", "in.g2o", "--overwrite"], ins),
        Case(cls, "rlpgo-compare: --plot is the input, --overwrite",
             ["rlpgo-compare", "in.g2o", "--plot", "in.g2o", "--overwrite"], ins),
        Case(cls, "rlpgo-compare: --plot in missing folders",
             ["rlpgo-compare", "in.g2o", "--plot", "a/b/plot.png"], ins, [], "any"),
        Case(cls, "rlpgo-compare: --methods bogus",
             ["rlpgo-compare", "in.g2o", "--methods", "odometry,bogus"], ins),
        Case(cls, "rlpgo-compare: --methods lago on a 3D file",
             ["rlpgo-compare", "in.g2o", "--methods", "lago"], {"in.g2o": pose3}),
        Case(cls, "rlpgo-compare: --ground-truth with other ids",
             ["rlpgo-compare", "in.g2o", "--ground-truth", "gt.g2o"],
             {**ins, "gt.g2o": text(se2_lines(6, range(100, 106)))}, [], "error", KEYS),
        Case(cls, "rlpgo-compare: --ground-truth of a 3D graph for a 2D one",
             ["rlpgo-compare", "in.g2o", "--ground-truth", "gt.g2o"],
             {**ins, "gt.g2o": pose3}, [], "error"),
        Case(cls, "rlpgo-compare: the same file twice", ["rlpgo-compare", "in.g2o", "in.g2o"],
             ins, [], "any"),
        Case(cls, "rlpgo-generate: output exists", ["rlpgo-generate", "-o", "g.g2o"],
             {"g.g2o": b"keep\n"}, where="g.g2o"),
        Case(cls, "rlpgo-generate: output /dev/full", ["rlpgo-generate", "-o", "/dev/full"],
             {}, where="/dev/full"),
        Case(cls, "rlpgo-generate: output in a missing folder",
             ["rlpgo-generate", "-o", "missing/g.g2o"], {}, where="missing"),
        Case(cls, "rlpgo-generate: --ground-truth is the output",
             ["rlpgo-generate", "-o", "g.g2o", "--ground-truth", "g.g2o"], {}),
        Case(cls, "rlpgo-generate: --outliers-out is the output",
             ["rlpgo-generate", "-o", "g.g2o", "--outliers", "0.1", "--outliers-out",
              "g.g2o"], {}),
        Case(cls, "rlpgo-generate: --ground-truth /dev/full (output must not be left)",
             ["rlpgo-generate", "-o", "g.g2o", "--ground-truth", "/dev/full"], {},
             where="/dev/full"),
        Case(cls, "rlpgo-generate: --ranges into a .g2o",
             ["rlpgo-generate", "--ranges", "3", "-o", "g.g2o"], {}),
        Case(cls, "rlpgo-generate: --dim 3 into a .pyfg",
             ["rlpgo-generate", "--dim", "3", "-o", "g.pyfg"], {}),
        Case(cls, "rlpgo-generate: --n 1", ["rlpgo-generate", "--n", "1", "-o", "g.g2o"], {}),
        Case(cls, "rlpgo-generate: --landmarks with --sensor-range 1e-6",
             ["rlpgo-generate", "--landmarks", "5", "--sensor-range", "1e-6", "-o", "g.g2o"],
             {}, ["g.g2o"], "any"),
        Case(cls, "rlpgo-generate: --outliers 0.99 --outlier-mode group --group-size 10000",
             ["rlpgo-generate", "--n", "50", "--outliers", "0.99", "--outlier-mode", "group",
              "--group-size", "10000", "-o", "g.g2o"], {}, ["g.g2o"], "any"),
        Case(cls, "rlpgo-example: unknown name", ["rlpgo-example", "nothing.g2o"], {},
             where="nothing"),
        Case(cls, "rlpgo-example: a path out of the data folder",
             ["rlpgo-example", "../../../../../etc/passwd"], {}),
        Case(cls, "rlpgo-example: empty name", ["rlpgo-example", ""], {}),
    ]
    for case in cases:
        if not case.outputs and case.argv[0] == "rlpgo-init" and case.expect == "ok":
            case.outputs = out
    return cases


# --- class: model files -----------------------------------------------------------------------

class _Payload:
    """A pickle that would run a command when loaded: no model file may execute it."""

    def __reduce__(self):
        return (os.system, ("touch PWNED",))


def _model_zip(config: bytes | None, weights: bytes | None) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        if config is not None:
            archive.writestr("config.json", config)
        if weights is not None:
            archive.writestr("actor.pt", weights)
    return buffer.getvalue()


def _bomb(folder: Path) -> None:
    """model.zip whose config.json inflates to 400 MB of JSON whitespace."""
    with zipfile.ZipFile(folder / "model.zip", "w", zipfile.ZIP_DEFLATED) as archive:
        with archive.open("config.json", "w", force_zip64=True) as member:
            member.write(b"{")
            chunk = b" " * (1 << 20)
            for _ in range(400):
                member.write(chunk)
            member.write(b"}")
        archive.writestr("actor.pt", b"")


def _lying_size(folder: Path, data: bytes) -> None:
    """model.zip whose headers say config.json holds 100 bytes; it inflates to 2 MB."""
    raw = bytearray(data)
    for signature, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        start = raw.find(signature)
        while start >= 0:
            name_length = int.from_bytes(raw[start + (26 if offset == 22 else 28):][:2],
                                         "little")
            name_at = start + (30 if offset == 22 else 46)
            if bytes(raw[name_at:name_at + name_length]) == b"config.json":
                raw[start + offset:start + offset + 4] = (100).to_bytes(4, "little")
            start = raw.find(signature, start + 4)
    (folder / "model.zip").write_bytes(bytes(raw))


def model_cases(preset: Path) -> list[Case]:
    cls = "model file"
    good = preset.read_bytes()
    with zipfile.ZipFile(preset) as archive:
        config = json.loads(archive.read("config.json"))
        weights = archive.read("actor.pt")
    body = text(se2_lines())

    def case(name: str, model: bytes | None, expect: str = "error", setup=None,
             where: str | None = "model") -> Case:
        files = {"in.g2o": body}
        if model is not None:
            files["model.zip"] = model
        return Case(cls, name, init("in.g2o", "out.g2o", "--method", "rl", "--model",
                                    "model.zip"), files, ["out.g2o"], expect, where, setup)

    flipped = bytearray(good)
    flipped[len(flipped) // 2] ^= 0xFF
    huge_config = {**config, "hidden": 1024, "env": {**config["env"], "n": 1_000_000}}
    return [
        case("the shipped preset4, copied", good, "ok", where=None),
        case("not a zip", b"PK\x03\x04 this is not a zip"),
        case("an empty file", b""),
        case("one byte flipped in the middle", bytes(flipped)),
        case("actor.pt is a pickle that runs a command",
             _model_zip(json.dumps(config).encode(), pickle.dumps(_Payload()))),
        case("config.json missing", _model_zip(None, weights)),
        case("actor.pt missing", _model_zip(json.dumps(config).encode(), None)),
        case("config.json not JSON", _model_zip(b"{not json", weights)),
        case("config.json format 2", _model_zip(json.dumps({**config, "format": 2}).encode(),
                                                weights)),
        case("config.json hidden 1024 for 64-wide weights",
             _model_zip(json.dumps(huge_config).encode(), weights)),
        case("config.json hidden 1e9", _model_zip(json.dumps({**config, "hidden": 10**9})
                                                  .encode(), weights)),
        case("config.json inflating to 400 MB", None, setup=_bomb),
        case("config.json larger than its headers say", None,
             setup=lambda folder: _lying_size(folder, _model_zip(
                 json.dumps(config).encode() + b" " * (2 << 20), weights))),
        case("model is a folder", None, setup=_mkdir("model.zip")),
    ]


# --- class: interrupts ------------------------------------------------------------------------

def interrupt_cases(big: bytes) -> list[Case]:
    cls = "interrupt"
    million = len(big) * 200  # the output of rlpgo-generate --n 1000000
    files = {"big.g2o": big}
    sigint, sigterm = signal.SIGINT, signal.SIGTERM
    every = init("big.g2o", "out.g2o", "--method", "all", "--json", "run.json")
    return [
        Case(cls, "SIGINT at 1 s, --method all", every, files, interrupt=(sigint, 1.0)),
        Case(cls, "SIGINT at 0.3 s (importing)", init("big.g2o", "out.g2o"), files,
             interrupt=(sigint, 0.3)),
        Case(cls, "SIGINT at 6 s, --method all (optimizing)", every, files,
             interrupt=(sigint, 6.0)),
        Case(cls, "SIGTERM at 6 s, --method all", every, files, interrupt=(sigterm, 6.0)),
        Case(cls, "SIGINT at 1 s, --robust", init("big.g2o", "out.g2o", "--robust",
                                                 "--outliers-out", "rej.txt"), files,
             interrupt=(sigint, 1.0)),
        Case(cls, "SIGINT at 2 s, rlpgo-compare --json",
             ["rlpgo-compare", "big.g2o", "--json", "c.json"], files,
             interrupt=(sigint, 2.0)),
        Case(cls, "SIGINT at 1 s, rlpgo-generate --n 1000000",
             ["rlpgo-generate", "--n", "1000000", "-o", "g.g2o", "--ground-truth", "gt.g2o"],
             {}, interrupt=(sigint, 1.0), work_bytes=million),
        Case(cls, "SIGTERM at 3 s, rlpgo-generate --n 1000000",
             ["rlpgo-generate", "--n", "1000000", "-o", "g.g2o"], {},
             interrupt=(sigterm, 3.0), work_bytes=million),
    ]


# --- running ----------------------------------------------------------------------------------

def _display(arg: Arg) -> str:
    raw = arg if isinstance(arg, bytes) else os.fsencode(arg)
    return raw.decode("utf-8", "backslashreplace")


def command_text(argv: Sequence[Arg]) -> str:
    return shlex.join(_display(arg) for arg in argv)


def snapshot(folder: Path) -> dict[bytes, tuple]:
    """Every entry under ``folder`` (links not followed): a link's target, a file's digest."""
    found: dict[bytes, tuple] = {}
    base = os.fsencode(folder)
    for top, folders, files in os.walk(base):
        for name in folders + files:
            path = os.path.join(top, name)
            relative = os.path.relpath(path, base)
            info = os.lstat(path)
            if stat.S_ISLNK(info.st_mode):
                found[relative] = ("link", os.readlink(path))
            elif stat.S_ISDIR(info.st_mode):
                found[relative] = ("dir",)
            elif stat.S_ISREG(info.st_mode):
                digest = hashlib.sha256()
                with open(path, "rb") as stream:
                    for chunk in iter(lambda: stream.read(1 << 20), b""):
                        digest.update(chunk)
                found[relative] = ("file", digest.hexdigest(), info.st_size)
            else:
                found[relative] = ("other", info.st_mode)
    return found


def _spawn(argv: list[Arg], cwd: Path, stdout: int, stderr: int,
           interrupt: tuple[int, float] | None) -> tuple[int, float, float, bool, float | None]:
    """Run ``argv``: (exit status, wall seconds, peak MB, timed out, seconds from the fork
    to the interrupt: None if it ended before)."""
    started = time.monotonic()
    process = subprocess.Popen(argv, cwd=cwd, stdin=subprocess.DEVNULL, stdout=stdout,
                               stderr=stderr)
    sent: float | None = None
    timed_out = False
    while True:
        pid, status, usage = os.wait4(process.pid, os.WNOHANG)
        if pid:
            break
        elapsed = time.monotonic() - started
        if interrupt and sent is None and elapsed >= interrupt[1]:
            os.kill(process.pid, interrupt[0])
            sent = elapsed
        if elapsed > TIME_LIMIT_S and not timed_out:
            os.kill(process.pid, signal.SIGKILL)
            timed_out = True
        time.sleep(0.01)
    code = os.waitstatus_to_exitcode(status)
    process.returncode = code  # reaped here: Popen must not wait for it again
    return code, time.monotonic() - started, usage.ru_maxrss / 1024.0, timed_out, sent


def _scan_non_finite(path: Path) -> bool:
    with open(path, "rb") as stream:
        tail = b""
        read = 0
        while read < OUTPUT_SCAN_BYTES:
            chunk = stream.read(1 << 20)
            if not chunk:
                return False
            read += len(chunk)
            if NON_FINITE.search(tail + chunk):
                return True
            tail = chunk[-16:]
    return False


def _is_char_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False


def run_case(case: Case, folder: Path, floor_mb: float) -> dict:
    folder.mkdir(parents=True)
    for name, data in case.files.items():
        with open(os.path.join(os.fsencode(folder), os.fsencode(name)), "wb") as stream:
            stream.write(data)
    if case.setup:
        case.setup(folder)
    before = snapshot(folder)
    input_bytes = sum(entry[2] for entry in before.values() if entry[0] == "file")
    if case.work_bytes is not None:
        input_bytes = max(input_bytes, case.work_bytes)
    argv: list[Arg] = [str(BIN / case.argv[0]), *case.argv[1:]]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        code, seconds, peak_mb, timed_out, sent_at = _spawn(
            argv, folder, out.fileno(), err.fileno(), case.interrupt)
        out.seek(0)
        err.seek(0)
        stdout = out.read(1 << 20).decode("utf-8", "backslashreplace")
        stderr = err.read(1 << 20).decode("utf-8", "backslashreplace")
    after = snapshot(folder)
    limit_mb = max(floor_mb, MEMORY_FACTOR * input_bytes / 2**20)
    failures: list[str] = []
    offending: list[str] = []
    both = (stderr + "\n" + stdout).splitlines()
    if any(TRACEBACK in line for line in both):
        failures.append("traceback")
        start = next(k for k, line in enumerate(both) if TRACEBACK in line)
        offending += both[start:start + 3] + [line for line in both[start:] if
                                             re.match(r"^\w+(\.\w+)*(Error|Exception|"
                                                      r"Interrupt|Exit)\b", line)][-1:]
    internal = [line for line in both if INTERNAL.search(line)]
    internal += [line for line in both if SINGULAR.search(line) and not LOCATED.search(
        SINGULAR.sub("", line))]
    if internal:
        failures.append("internal text")
        offending += [line for line in internal if line not in offending][:4]
    sent = case.interrupt[0] if case.interrupt and sent_at is not None else None
    stop_s = seconds - sent_at if sent_at is not None else None
    if timed_out:
        failures.append(f"ran past {TIME_LIMIT_S:.0f} s")
    elif (code < 0 and -code != sent) or code in SIGNAL_CODES:
        failures.append(f"ended by signal ({code})")
    if sent is not None and code == 0:
        failures.append("ran on after the signal and exited 0")
    elif stop_s is not None and stop_s > STOP_LIMIT_S:
        failures.append(f"stopped {stop_s:.1f} s after the signal")
    if peak_mb > limit_mb:
        failures.append(f"peak {peak_mb:.0f} MB > {limit_mb:.0f} MB")
    changed = [_display(name) for name, entry in before.items()
               if after.get(name) != entry and _display(name) not in
               [_display(m) for m in case.may_change]]
    if changed:
        failures.append("changed or lost: " + ", ".join(changed))
    new = [_display(name) for name in after if name not in before]
    temps = [name for name in new if re.search(r"\.rlpgo-.*\.tmp", name)]
    if temps:
        failures.append("temporary files left: " + ", ".join(temps))
    if code != 0 and [name for name in new if name not in temps]:
        failures.append("left after a failed run: " + ", ".join(
            name for name in new if name not in temps))
    for path in ("/dev/full", "/dev/null"):
        if not _is_char_device(path):
            failures.append(f"{path} is no longer a device")
    missing, non_finite = [], []
    if code == 0:
        for name in case.outputs:
            path = Path(os.fsdecode(os.path.join(os.fsencode(folder), os.fsencode(name))))
            if os.path.isabs(os.fsdecode(name)):
                continue
            if not path.is_file():
                missing.append(_display(name))
            elif _scan_non_finite(path):
                non_finite.append(_display(name))
        if missing:
            failures.append("exit 0 without " + ", ".join(missing))
        if non_finite:
            failures.append("NaN or inf written in " + ", ".join(non_finite))
    error_lines = [line for line in stderr.splitlines() if line.startswith("Error:")]
    if code != 0 and not timed_out:
        if len(error_lines) != 1:
            failures.append(f"{len(error_lines)} 'Error:' lines")
            offending += [line for line in stderr.splitlines() if line.strip()][:3]
        elif case.where and not re.search(case.where, error_lines[0]):
            failures.append(f"error names no location (/{case.where}/)")
            offending.append(error_lines[0])
    surprise = None
    told = re.search(r":(\d+): ", error_lines[0]) if error_lines else None
    if case.expect == "error" and code == 0:
        surprise = "accepted"
    elif case.expect == "ok" and code != 0:
        surprise = "refused"
    elif told and case.line and int(told.group(1)) != case.line:
        surprise = f"told at line {told.group(1)}, not at the hostile line {case.line}"
    elif code == 0 and NON_FINITE.search(stdout.encode()):
        surprise = "accepted, printed nan or inf"
    return {
        "class": case.cls, "name": case.name, "command": command_text(case.argv),
        "interrupt": ([signal.Signals(case.interrupt[0]).name, case.interrupt[1]]
                      if case.interrupt else None),
        "returncode": code, "timed_out": timed_out, "seconds": round(seconds, 3),
        "stop_seconds": round(stop_s, 3) if stop_s is not None else None,
        "peak_mb": round(peak_mb, 1), "input_bytes": input_bytes,
        "memory_limit_mb": round(limit_mb, 1), "expect": case.expect, "surprise": surprise,
        "failures": failures, "offending": list(dict.fromkeys(offending))[:8],
        "error_lines": error_lines[:3],
        "stdout_head": stdout.splitlines()[:6], "stderr_head": stderr.splitlines()[:8],
        "new_files": new[:20], "changed": changed,
    }


def _console(name: str, *args: str) -> str:
    done = subprocess.run([str(BIN / name), *args], capture_output=True, text=True,
                          check=True)
    return done.stdout.strip()


def prepare(cache: Path) -> dict[str, Path]:
    """The generated and example inputs, made once."""
    paths = {"goats": Path(_console("rlpgo-example", "goats_15.pyfg")),
             "pose3": Path(_console("rlpgo-example", "pose3example.txt")),
             "preset": ROOT / "models" / "preset4.zip"}
    for dim in (2, 3):
        target = cache / f"landmarks{dim}d.g2o"
        subprocess.run([str(BIN / "rlpgo-generate"), "--dim", str(dim), "--n", "40",
                        "--landmarks", "12", "--seed", "3", "-o", str(target)],
                       check=True, capture_output=True)
        paths[f"lm{dim}"] = target
    paths["big"] = cache / "big.g2o"
    subprocess.run([str(BIN / "rlpgo-generate"), "--n", "5000", "--seed", "1", "-o",
                    str(paths["big"])], check=True, capture_output=True)
    return paths


def all_cases(cache: Path) -> list[Case]:
    paths = prepare(cache)
    pose3 = paths["pose3"].read_bytes()
    return [*malformed_cases(), *semantic_cases(), *graph_cases(), *file_cases(),
            *generated_cases(cache), *pyfg_cases(paths["goats"]),
            *command_cases(text(lm2_lines()), text(lm3_lines()), pose3),
            *model_cases(paths["preset"]), *interrupt_cases(paths["big"].read_bytes())]


def measure_floor(work: Path) -> dict[str, float]:
    """Peaks of ``true`` (this process's footprint carried into every child) and of
    rlpgo-init on a 6-pose graph, by default and with --method all (torch)."""
    folder = work / "floor"
    folder.mkdir()
    (folder / "in.g2o").write_bytes(text(se2_lines()))
    peaks = {}
    with open(os.devnull, "wb") as null:
        for label, argv in (("true", ["true"]),
                            ("rlpgo-init", [str(BIN / "rlpgo-init"), "in.g2o", "-o", "a.g2o"]),
                            ("rlpgo-init --method all",
                             [str(BIN / "rlpgo-init"), "in.g2o", "-o", "b.g2o", "--method",
                              "all"])):
            peak = _spawn(argv, folder, null.fileno(), null.fileno(), None)[2]
            peaks[label] = round(peak, 1)
    return peaks


# --- report -----------------------------------------------------------------------------------

def _cell(text_: str) -> str:
    return text_.replace("|", "\\|").replace("\n", " ")


def report(records: list[dict], peaks: dict[str, float], floor_mb: float, command: str,
           seconds: float) -> str:
    classes: dict[str, list[dict]] = {}
    for record in records:
        classes.setdefault(record["class"], []).append(record)
    failing = [r for r in records if r["failures"]]
    lines = [
        "# Hostile round",
        "",
        f"`{command}`: {len(records)} cases, {len(failing)} failing, "
        f"{seconds:.0f} s in all (one case at a time, 60 s limit each).",
        "",
        f"Memory: a case fails above {MEMORY_FACTOR} x its input's size, floor "
        f"{floor_mb:.0f} MB (the larger of {FLOOR_MB:.0f} MB and 1.25 x the largest of "
        + ", ".join(f"{k} {v:.0f} MB" for k, v in peaks.items())
        + " on a 6-pose graph; `true` is this script's own footprint, in every peak).",
        "",
        "| class | cases | failures | surprises |",
        "|---|---:|---:|---:|",
    ]
    for name, group in classes.items():
        lines.append(f"| {name} | {len(group)} | {sum(bool(r['failures']) for r in group)} | "
                     f"{sum(bool(r['surprise']) for r in group)} |")
    lines.append(f"| all | {len(records)} | {len(failing)} | "
                 f"{sum(bool(r['surprise']) for r in records)} |")
    lines += ["", "## Failing cases", ""]
    if not failing:
        lines.append("None.")
    for record in failing:
        lines += [f"### {record['class']}: {record['name']}", "",
                  "```", record["command"] + (f"   # {record['interrupt'][0]} after "
                                              f"{record['interrupt'][1]} s"
                                              if record["interrupt"] else ""), "```", "",
                  f"exit {record['returncode']}, {record['seconds']:.1f} s, peak "
                  f"{record['peak_mb']:.0f} MB (limit {record['memory_limit_mb']:.0f} MB), "
                  f"input {record['input_bytes']} bytes", "",
                  "- " + "\n- ".join(_cell(f) for f in record["failures"]), ""]
        shown = list(dict.fromkeys(record["offending"] + record["error_lines"])) or \
            record["stderr_head"][:4] or record["stdout_head"][:4]
        if shown:
            lines += ["```", *[line[:300] for line in shown], "```", ""]
    surprising = [r for r in records if r["surprise"]]
    lines += ["## Surprises (not failures)", "",
              "Inputs this script expected refused that were accepted, or the reverse; errors "
              "told at another line than the one changed; nan or inf printed by a run that "
              "exited 0.", "",
              "| class | case | outcome | exit | first line |", "|---|---|---|---:|---|"]
    if not surprising:
        lines[-2:] = ["None."]
    for record in surprising:
        nan_line = [line for line in record["stdout_head"]
                    if NON_FINITE.search(line.encode())]
        first = (record["error_lines"] or nan_line or record["stderr_head"]
                 or record["stdout_head"][-1:] or [""])[0]
        lines.append(f"| {record['class']} | {_cell(record['name'])} | {record['surprise']} | "
                     f"{record['returncode']} | {_cell(first[:160])} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help="run the cases whose 'class: name' matches this regex")
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder")
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    parser.add_argument("--name", default="hostile", help="results file name")
    options = parser.parse_args(argv)
    # a signal ignored here (a background job's SIGINT) stays ignored in every child, and a
    # Python child then never sees Ctrl-C: give SIGINT a handler, which exec resets to default
    signal.signal(signal.SIGINT, signal.default_int_handler)
    work = Path(tempfile.mkdtemp(prefix="rlpgo_hostile_"))
    try:
        cache = work / "cache"
        cache.mkdir()
        cases = all_cases(cache)
        if options.only:
            cases = [c for c in cases if re.search(options.only, f"{c.cls}: {c.name}")]
        if options.list:
            for case in cases:
                print(f"{case.cls}: {case.name}: {command_text(case.argv)}")
            print(f"{len(cases)} cases")
            return 0
        started = time.monotonic()
        peaks = measure_floor(work)
        floor_mb = max(FLOOR_MB, 1.25 * max(peaks.values()))
        print(f"floor {floor_mb:.0f} MB ({peaks})", flush=True)
        records = []
        for index, case in enumerate(cases):
            record = run_case(case, work / f"case{index:03d}", floor_mb)
            records.append(record)
            mark = "FAIL " + "; ".join(record["failures"]) if record["failures"] else "ok"
            print(f"[{index + 1}/{len(cases)}] {case.cls}: {case.name}: exit "
                  f"{record['returncode']}, {record['seconds']:.1f} s, "
                  f"{record['peak_mb']:.0f} MB: {mark}", flush=True)
        seconds = time.monotonic() - started
        command = "python benchmarks/hostile.py" + (
            f" --only {shlex.quote(options.only)}" if options.only else "")
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / f"{options.name}.json").write_text(json.dumps(records, indent=1) + "\n")
        (RESULTS / f"{options.name}.md").write_text(
            report(records, peaks, floor_mb, command, seconds))
        failing = sum(bool(r["failures"]) for r in records)
        print(f"{len(records)} cases, {failing} failing; wrote "
              f"{RESULTS / options.name}.json and .md")
        return 0
    finally:
        if options.keep:
            print(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
