"""A command's graph inputs (g2o, or PyFG by its extension): each file's dimension, its
graph, and what the reader noted."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import gtsam

from rlpgo_cli.formats import is_pyfg
from rlpgo_gtsam.errors import InformationWarning
from rlpgo_gtsam.graph import extract_pose_graph
from rlpgo_gtsam.io import read_g2o_extracted

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph
    from rlpgo_gtsam.io.pyfg import PyfgTimes


@dataclass(eq=False)
class InputGraph:
    """One input as read.

    Attributes:
        graph, values: what the reader of the file's dimension made of it.
        notes: what the reader changed, one line each (its
            :class:`~rlpgo_gtsam.errors.InformationWarning` messages): a command prints them
            as ``note:`` lines.
    """

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    notes: list[str] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)  # each factor's file line
    read_extraction: PoseGraph | None = None  # the planar reader's, where it made one
    times: PyfgTimes | None = None  # a PyFG file's timestamps, for its output

    def pose_graph(self) -> PoseGraph:
        """The graph's one extraction: the planar reader's (the same arrays, without a
        second walk over the factors), else :func:`~rlpgo_gtsam.graph.extract_pose_graph`
        (which raises what it refuses)."""
        if self.read_extraction is not None:
            return self.read_extraction
        return extract_pose_graph(self.graph, self.values)


def read_input(path: Path) -> InputGraph:
    """Read a planar or a 3D g2o file
    (:func:`~rlpgo_gtsam.io.read_g2o_extracted`), with each factor's file line
    and the reader's information warnings as notes; any other warning is passed on. A
    ``.pyfg`` file is read by :func:`~rlpgo_gtsam.io.pyfg.read_pyfg_file`, its timestamps
    kept."""
    if is_pyfg(path):
        from rlpgo_gtsam.io.pyfg import read_pyfg_file  # a g2o run loads none of it

        read = read_pyfg_file(path)
        return InputGraph(read.graph, read.values, [], read.lines, times=read.times)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", InformationWarning)
        graph, values, factor_lines, extraction = read_g2o_extracted(path)
    notes = []
    for warning in caught:
        if issubclass(warning.category, InformationWarning):
            notes.append(str(warning.message))
        else:
            warnings.warn_explicit(warning.message, warning.category, warning.filename,
                                   warning.lineno)
    return InputGraph(graph, values, notes, factor_lines, extraction)
