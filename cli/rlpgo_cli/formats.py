"""Which reader and writer a command uses: a file's extension picks them, ``.pyfg`` (any
case) CORA's PyFG, planar or 3D (:mod:`rlpgo_gtsam.io.pyfg`), any other g2o."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import gtsam

from rlpgo_gtsam.errors import OutputError
from rlpgo_gtsam.groups import SE3, Group
from rlpgo_gtsam.io import file_group, g2o_text, read_poses
from rlpgo_gtsam.landmarks import RANGE_FACTORS

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph
    from rlpgo_gtsam.io.pyfg import PyfgTimes

# the PyFG module is imported where a PyFG file is met: a g2o run loads none of it

PYFG = ".pyfg"


def is_pyfg(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a PyFG file (its extension)."""
    return Path(path).suffix.lower() == PYFG


def input_group(path: Path) -> Group:
    """The pose group of an input: a PyFG file's (:func:`~rlpgo_gtsam.io.pyfg.pyfg_group`)
    or a g2o file's (:func:`~rlpgo_gtsam.io.file_group`)."""
    if not is_pyfg(path):
        return file_group(path)
    from rlpgo_gtsam.io.pyfg import pyfg_group

    return pyfg_group(path)


def read_truth(path: Path) -> gtsam.Values:
    """The true poses of a ground-truth file: a g2o file's vertex poses
    (:func:`~rlpgo_gtsam.io.read_poses`), or a PyFG file's pose values (``VERTEX_SE2`` or
    ``VERTEX_SE3:QUAT``)."""
    if not is_pyfg(path):
        return read_poses(path)
    from rlpgo_gtsam.io.pyfg import read_pyfg_file

    read = read_pyfg_file(path)
    if read.group is SE3:
        return gtsam.utilities.allPose3s(read.values)
    return gtsam.utilities.allPose2s(read.values)


def check_graph_output(path: Path, graph: gtsam.NonlinearFactorGraph) -> None:
    """Refuse, before any work, an output whose format cannot hold ``graph``: ranges in a g2o
    file (it has no range line), a factor a PyFG line cannot hold.

    Raises:
        OutputError: naming the output and what it cannot hold.
    """
    if is_pyfg(path):
        from rlpgo_gtsam.io.pyfg import check_pyfg_graph

        try:
            check_pyfg_graph(graph)
        except OutputError as error:
            raise OutputError(f"{path}: {error}") from None
        return
    ranges = sum(isinstance(graph.at(k), RANGE_FACTORS) for k in range(graph.size()))
    if ranges:
        raise OutputError(f"{path}: a g2o file has no line for ranges, and the graph holds "
                          f"{ranges}; give an output ending in {PYFG}")


def graph_text(path: Path, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               pose_graph: PoseGraph | None = None, times: PyfgTimes | None = None) -> str:
    """The text of ``graph`` and ``values`` in the format ``path`` names: PyFG with the
    input's timestamps ``times``, or g2o (``pose_graph``: the graph's extraction, which
    spares the writer a walk over the factors)."""
    if is_pyfg(path):
        from rlpgo_gtsam.io.pyfg import pyfg_text

        return pyfg_text(graph, values, times)
    return g2o_text(graph, values, pose_graph)
