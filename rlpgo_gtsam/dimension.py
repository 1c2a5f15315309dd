"""Planar or 3D files: the one place that tells them apart and hands a file, or a method
name, to its dimension's code (reading and writing g2o, the initializers).

The 3D reader and writer and the 3D initializers (:mod:`~rlpgo_gtsam.g2o3d`,
:mod:`~rlpgo_gtsam.initializers3d` and the relaxation, chordal and translation modules
they import) are imported here only once a 3D file or graph is seen, so a planar command
does not load them (about 7 ms of ``rlpgo-init``'s start-up on an 800-pose file). Graphs
are told apart by :func:`~rlpgo_gtsam.graph3d.graph_dimension` and extracted by
:func:`~rlpgo_gtsam.graph3d.extract_pose_graph`, re-exported here.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gtsam

from rlpgo_gtsam.g2o import (
    TAGS_2D,
    TAGS_3D,
    g2o_text,
    line_records,
    read_g2o_extracted,
    read_g2o_lines,
    write_g2o,
)
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.graph3d import extract_pose_graph, graph_dimension
from rlpgo_gtsam.initializers import Initializer, check_method, make_initializer

if TYPE_CHECKING:
    from rlpgo_gtsam.graph3d import AnyPoseGraph

__all__ = ["METHODS_3D", "COMPARISON_3D", "g2o_dimension", "graph_dimension",
           "extract_pose_graph", "read_pose_graph", "read_pose_graph_lines",
           "read_pose_graph_extracted", "pose_graph_text", "write_pose_graph",
           "check_method_3d", "check_method_for", "make_initializer_for"]

# The 3D initializers' names, in :data:`~rlpgo_gtsam.initializers3d.INITIALIZERS_3D`'s order
# (a test holds the two equal): here so that checking a planar command's --method, or
# printing its --help, needs no 3D module.
METHODS_3D = ("odometry", "chordal", "certified", "initialize_pose3", "fastsync", "shonan")
# The 3D comparison rows, the certified relaxation first (ties go to the earlier row):
# rlpgo-compare's default on a 3D file and rlpgo-init --method all's.
COMPARISON_3D = ("certified", *(name for name in METHODS_3D if name != "certified"))


def g2o_dimension(path: str | os.PathLike[str]) -> int:
    """3 if the first pose line of the g2o file at ``path`` is a 3D one (``VERTEX_SE3:QUAT``,
    ``EDGE_SE3:QUAT``, any tag of :data:`~rlpgo_gtsam.g2o.TAGS_3D`), else 2.

    It reads up to that line only: a later line of the other dimension is the reader's
    ``file:line`` error (a file holds 2D or 3D lines, not both). A file without a pose line
    is 2: the planar reader names what it holds.

    Raises:
        G2oFormatError: the file is missing or unreadable, or a line before the first pose
            line is (too long, binary, not UTF-8).
    """
    for _, tag, _ in line_records(Path(path)):
        upper = tag.upper()
        if upper.startswith(TAGS_3D):
            return 3
        if upper.startswith(TAGS_2D) or tag != "FIX":
            return 2  # an unknown tag: the planar reader names it
    return 2


def read_pose_graph(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph,
                                                          gtsam.Values]:
    """Read a g2o file of either dimension (:func:`g2o_dimension`): a ``BetweenFactorPose2``
    graph by :func:`~rlpgo_gtsam.g2o.read_g2o` or a ``BetweenFactorPose3`` one by
    :func:`~rlpgo_gtsam.g2o3d.read_g2o3d`, with their ``file:line`` errors.

    Raises:
        G2oFormatError: as the reader of the file's dimension.
    """
    graph, values, _lines = read_pose_graph_lines(path)
    return graph, values


def read_pose_graph_lines(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int]]:
    """:func:`read_pose_graph`, and the file line of each factor
    (:func:`~rlpgo_gtsam.g2o.read_g2o_lines` or
    :func:`~rlpgo_gtsam.g2o3d.read_g2o3d_lines`).

    Raises:
        G2oFormatError: as the reader of the file's dimension.
    """
    if g2o_dimension(path) == 3:
        from rlpgo_gtsam.g2o3d import read_g2o3d_lines

        return read_g2o3d_lines(path)
    return read_g2o_lines(path)


def read_pose_graph_extracted(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], PoseGraph2D | None]:
    """:func:`read_pose_graph_lines`, and for a planar file the graph's extraction as its
    reader made it (:func:`~rlpgo_gtsam.g2o.read_g2o_extracted`); None for a 3D file, or
    where the extraction would refuse the graph: extract it then
    (:func:`extract_pose_graph`).

    Raises:
        G2oFormatError: as the reader of the file's dimension.
    """
    if g2o_dimension(path) == 3:
        from rlpgo_gtsam.g2o3d import read_g2o3d_lines

        return (*read_g2o3d_lines(path), None)
    return read_g2o_extracted(path)


def pose_graph_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                    pose_graph: AnyPoseGraph | None = None) -> str:
    """The g2o text of a planar or a 3D graph (:func:`graph_dimension`):
    :func:`~rlpgo_gtsam.g2o.g2o_text` (given ``pose_graph``, the graph's extraction, from its
    arrays) or :func:`~rlpgo_gtsam.g2o3d.g2o3d_text`."""
    if graph_dimension(graph) == 3:
        from rlpgo_gtsam.g2o3d import g2o3d_text

        return g2o3d_text(graph, values)
    return g2o_text(graph, values, pose_graph if isinstance(pose_graph, PoseGraph2D) else None)


def write_pose_graph(path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph,
                     values: gtsam.Values) -> None:
    """Write a planar or a 3D graph as g2o, atomically (:func:`~rlpgo_gtsam.g2o.write_g2o` or
    :func:`~rlpgo_gtsam.g2o3d.write_g2o3d`).

    Raises:
        OutputError: as the writer of the graph's dimension.
    """
    if graph_dimension(graph) == 3:
        from rlpgo_gtsam.g2o3d import write_g2o3d

        write_g2o3d(path, graph, values)
    else:
        write_g2o(path, graph, values)


def check_method_3d(name: str) -> None:
    """:func:`~rlpgo_gtsam.initializers3d.check_method_3d` (raise :class:`RlpgoError` unless
    ``name`` is a 3D method), which a 3D name passes without the 3D modules loaded."""
    if name not in METHODS_3D:
        from rlpgo_gtsam.initializers3d import check_method_3d as check

        check(name)


def check_method_for(dimension: int, name: str) -> None:
    """:func:`~rlpgo_gtsam.initializers.check_method` on a planar graph, else
    :func:`check_method_3d`."""
    (check_method_3d if dimension == 3 else check_method)(name)


def make_initializer_for(pose_graph: AnyPoseGraph, name: str, **options: Any) -> Initializer:
    """:func:`~rlpgo_gtsam.initializers.make_initializer` for a planar graph,
    :func:`~rlpgo_gtsam.initializers3d.make_initializer_3d` for a 3D one."""
    if pose_graph.dimension == 3:
        from rlpgo_gtsam.initializers3d import make_initializer_3d

        return make_initializer_3d(name, **options)
    return make_initializer(name, **options)
