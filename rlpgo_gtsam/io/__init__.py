"""Reading and writing g2o files, planar or 3D, as GTSAM graphs, with line-by-line validation.

``gtsam.readG2o`` names no line when a file is malformed, and accepts files that no
initializer can work on. :func:`read_g2o` checks every line itself and raises a
:class:`~rlpgo_gtsam.errors.G2oFormatError` of the form ``file:line: reason``.

Supported lines (a file holds the lines of one pose group, found by :func:`file_group`)::

    VERTEX_SE2 id x y theta
    EDGE_SE2 i j dx dy dtheta I_xx I_xy I_xt I_yy I_yt I_tt     (upper triangle, g2o order)
    VERTEX_XY id x y                                            (landmark l<id>)
    EDGE_SE2_XY i j dx dy I_xx I_xy I_yy                        (pose i sees landmark j)
    LANDMARK2 i j dx dy I_xx I_xy I_yy                          (as EDGE_SE2_XY)
    BR i j bearing range sigma_bearing sigma_range              (GTSAM's)
    LANDMARK i j dx dy v1 v2 v3                                 (GTSAM's)
    VERTEX_SE3:QUAT id x y z qx qy qz qw
    EDGE_SE3:QUAT i j x y z qx qy qz qw I_11 I_12 ... I_66      (21 entries, upper triangle)
    VERTEX_TRACKXYZ id x y z                                    (landmark l<id>)
    PARAMS_SE3OFFSET k x y z qx qy qz qw                        (sensor k in the body frame)
    EDGE_SE3_TRACKXYZ i j k dx dy dz I_11 I_12 I_13 I_22 I_23 I_33
    FIX id [id ...]
    # comment

Lines longer than :data:`MAX_LINE_BYTES` (64 KiB) are refused, so that a file without
newlines is read in bounded memory. The 3D information is in g2o's order (translation
first); the graph holds it in GTSAM's tangent order (rotation first), as
``gtsam.readG2o(path, True)`` does, read by the 3D information rule
(:func:`~rlpgo_gtsam.information.information_rule_3d`): a matrix it does not take as it
is, or keeps indefinite, is told in an :class:`~rlpgo_gtsam.errors.InformationWarning` per
file and kind. Quaternions are normalized; a zero or non-finite one is an error. A
``FIX``-ed vertex becomes a prior factor with a constrained noise model: the pose is held
where its vertex line puts it (the first FIXed pose is the anchor). A file without vertex
lines gets its initial guess chained from the edges (i -> i+1 first, then through any edge).

Landmarks: a measurement ``i j`` is pose ``i`` seeing landmark ``j``, whose key is
``gtsam.symbol('l', j)`` (``gtsam.readG2o``'s name for them): landmark ids are their own, and
may repeat pose ids, as GTSAM's Victoria Park and cityTrees files do. ``EDGE_SE2_XY``,
``LANDMARK2`` and ``EDGE_SE3_TRACKXYZ`` hold the point in the pose's frame with its
information (upper triangle); ``EDGE_SE3_TRACKXYZ``'s is in the frame of the sensor
``PARAMS_SE3OFFSET k`` (before or after it in the file): ``offset * p`` in the body frame,
with the information rotated alike (``gtsam.readG2o`` takes only the identity offset).
Each becomes a ``BearingRangeFactor2D`` / ``BearingRangeFactor3D`` by
:func:`~rlpgo_gtsam.landmarks.bearing_range_factor` (the information carried to bearing-range
coordinates, as ``gtsam.readG2o`` reads ``EDGE_SE3_TRACKXYZ``). ``BR`` and ``LANDMARK`` read
as ``gtsam.readG2o`` reads them: ``BR`` a bearing (rad) and a range with diagonal standard
deviations; ``LANDMARK`` the point (dx, dy) as bearing ``atan2(dy, dx)`` and range, with
standard deviations ``sqrt(v1 / 10)`` rad and ``sqrt(v1)`` m where ``|v1 - v3| < 1e-4``
(v2 unused), else 1 and 1 (an :class:`~rlpgo_gtsam.errors.InformationWarning` names those
lines). ``gtsam.readG2o`` skips ``LANDMARK2``; here (dx, dy) is the point in pose i's
frame and its last three numbers the information. A landmark without a vertex line starts
at its first sighting in file order (the pose's value composed with the measured point);
a landmark vertex that nothing measures, a measurement at zero range, from a pose that has
no vertex (in a file with vertex lines; else no pose edge), or in an unknown sensor's
frame is an error naming its line. The writer writes ``VERTEX_XY`` and ``EDGE_SE2_XY``, or
``VERTEX_TRACKXYZ``, one identity ``PARAMS_SE3OFFSET 0`` and ``EDGE_SE3_TRACKXYZ``: the
same graph to rounding.

How each group's lines read is :mod:`~rlpgo_gtsam.io.formats`'; the line and token reading
:mod:`~rlpgo_gtsam.io.lines`'; the fast reader :mod:`~rlpgo_gtsam.io.scan`'; the careful
reader and the graph :mod:`~rlpgo_gtsam.io.read`'; the writers :mod:`~rlpgo_gtsam.io.write`'.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.graph import PoseGraph
from rlpgo_gtsam.groups import Group, graph_group
from rlpgo_gtsam.io.formats import Format, format_of
from rlpgo_gtsam.io.lines import MAX_LINE_BYTES, line_records
from rlpgo_gtsam.io.read import (
    build,
    group_of_lines,
    read_file,
    warn_changes,
    warn_landmark_changes,
)
from rlpgo_gtsam.io.write import EDGE_LIST_LINE, text_lines, text_of_extraction
from rlpgo_gtsam.io.write import edge_list_text as _edge_list_text

__all__ = ["read_g2o", "read_g2o_lines", "read_g2o_extracted", "read_poses", "write_g2o",
           "g2o_text", "g2o_text_lines", "edge_list_text", "file_group", "EDGE_LIST_LINE",
           "MAX_LINE_BYTES"]


def file_group(path: str | os.PathLike[str]) -> Group:
    """The pose group of the g2o file at ``path``: the one whose tags start its first pose
    or landmark line (``VERTEX_SE3:QUAT``, ``EDGE_SE3:QUAT``, any of ``SE3.g2o_tags``,
    ``PARAMS_SE3OFFSET``: SE3), else SE2.

    It reads up to that line only: a later line of the other group is the reader's
    ``file:line`` error (a file holds 2D or 3D lines, not both). A file without a pose or
    landmark line is SE2: the planar reader names what it holds.

    Raises:
        G2oFormatError: the file is missing or unreadable, or a line before the first pose
            line is (too long, binary, not UTF-8).
    """
    return group_of_lines(line_records(Path(path)))


def read_g2o(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a planar or a 3D g2o file (:func:`file_group`) into a GTSAM factor graph and
    initial values.

    Each edge becomes a between factor (``BetweenFactorPose2`` / ``BetweenFactorPose3``)
    whose Gaussian noise model holds the edge's full information (correlations kept); then
    each landmark measurement a bearing-range factor, in file order; then one constrained
    prior factor per ``FIX``-ed id. Keys are the file's ids (``l<id>`` for landmarks).

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed, or its graph is not
            connected; the message names the file and the line.
    """
    graph, values, _, _ = _read(Path(path), lines=False)
    return graph, values


def read_g2o_lines(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int]]:
    """:func:`read_g2o`, and the file line (1-based) each factor came from.

    Factor ``k`` is the ``k``-th edge line for the edges, in file order; then the landmark
    measurements, each with its line, in file order; then one prior factor per id of the
    ``FIX`` lines, each with its ``FIX`` line. ``lines[k]`` is the
    line of ``graph.at(k)``: what a message about a factor should name. A missing file
    raises :class:`~rlpgo_gtsam.errors.InputNotFoundError`, which is both a
    :class:`G2oFormatError` and a :class:`FileNotFoundError`.

    Raises:
        G2oFormatError: as :func:`read_g2o`.
    """
    graph, values, lines, _ = _read(Path(path))
    return graph, values, lines


def read_g2o_extracted(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], PoseGraph | None]:
    """:func:`read_g2o_lines`, and the graph's extraction
    (:func:`~rlpgo_gtsam.graph.extract_pose_graph`'s arrays, bit for bit) where the reader
    makes it from what it read (a planar file: MIT, Intel, FR079 save 10-19 ms of a walk over
    the factors); None for a 3D file, a file with landmark lines, or where the extraction
    would refuse the graph: extract it then (its ``GraphError`` is the caller's to raise).

    Raises:
        G2oFormatError: as :func:`read_g2o`.
    """
    return _read(Path(path), extract=True)


def read_poses(path: str | os.PathLike[str]) -> gtsam.Values:
    """The poses of a g2o file's vertex lines (``VERTEX_SE2``, or ``VERTEX_SE3:QUAT``), keyed
    by id: a ground truth, which needs poses and nothing else.

    Edge, landmark and ``FIX`` lines may be there (a ground truth written with its graph)
    and are read like any g2o line (a malformed one is an error), but they make no pose: a
    file of edges alone holds no poses, however they chain, and landmark vertices are left
    out.

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed, or has no vertex line;
            the message names the file (and the line).
    """
    path = Path(path)
    form, table = read_file(path)
    if not len(table.vertex_keys):
        raise G2oFormatError(path, None, f"holds no {form.vertex_tag} line: a ground truth "
                             "needs the true poses as vertex lines")
    order = np.argsort(table.vertex_keys, kind="stable")
    keys = table.vertex_keys[order]
    poses = form.take(form.poses(table.vertex_numbers), order)
    return form.values(keys, poses, table.vertex_text)


def _read(path: Path, lines: bool = True, extract: bool = False
          ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], PoseGraph | None]:
    form, table = read_file(path)
    warn_changes(path, form, table.changed, stacklevel=3)  # the caller of the public reader
    warn_landmark_changes(path, table.landmarks, stacklevel=3)
    return build(path, table, form, lines=lines, extract=extract)


def _graph_format(graph: gtsam.NonlinearFactorGraph) -> Format:
    return format_of(graph_group(graph))


def g2o_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
             pose_graph: PoseGraph | None = None) -> str:
    """The g2o text of ``graph`` and ``values``, planar or 3D by what the graph holds
    (:func:`~rlpgo_gtsam.groups.graph_group`): what :func:`write_g2o` writes.

    ``pose_graph``: the extraction of this very ``graph``, where the caller has it: a planar
    graph's measurements, informations and FIXed ids then come from its arrays, not from a
    second walk over the factors (the same text; MIT, Intel, FR079: 5-9 ms less).

    Raises:
        OutputError: a factor, value or information that a g2o file cannot hold.
    """
    form = _graph_format(graph)
    if pose_graph is not None:
        text = text_of_extraction(graph, values, pose_graph, form)
        if text is not None:
            return text
    return text_lines(graph, values, form)[0]


def g2o_text_lines(graph: gtsam.NonlinearFactorGraph,
                   values: gtsam.Values) -> tuple[str, list[int | None]]:
    """:func:`g2o_text`, and the line (1-based) of that text which holds each factor.

    ``lines[k]`` is the edge line of ``graph.at(k)`` (a landmark measurement's too), or the
    one ``FIX`` line for a prior, or None for an empty factor slot: the lines
    :func:`read_g2o_lines` names when it reads the text back.

    Raises:
        OutputError: a factor, value or information that a g2o file cannot hold.
    """
    return text_lines(graph, values, _graph_format(graph))


def write_g2o(path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph,
              values: gtsam.Values) -> None:
    """Write ``graph`` and ``values`` as a g2o file (:func:`g2o_text`), atomically.

    The text goes to a temporary file beside ``path`` that then replaces it, so a failed
    write leaves any existing file untouched. Positions round-trip exactly through
    :func:`read_g2o`; angles, quaternions and information entries are written with 15
    significant digits, so values read from a file with up to 15 digits come back exactly.
    Landmark measurements (points in the pose's frame, from bearing-range factors) are
    written with 15 significant digits too: the graph reads back with the same error to
    rounding.

    Raises:
        OutputError: ``path`` is a directory or cannot be written, or the graph holds what a
            g2o file cannot. (Refusing to overwrite an input is the caller's policy: the
            commands check it before any work.)
    """
    write_text(path, g2o_text(graph, values))


def edge_list_text(graph: gtsam.NonlinearFactorGraph, indices: list[int],
                   lines: Sequence[int | None], *, title: str, g2o_name: str) -> str:
    """A list of some edges of a g2o file, one a line: ``line <L> EDGE_SE2 <id_i> <id_j>``
    (:data:`EDGE_LIST_LINE`; ``EDGE_SE3:QUAT`` for a 3D graph).

    ``L`` is the edge's line in the g2o file ``g2o_name`` (``lines[k]`` for factor ``k``, as
    :func:`read_g2o_lines` or :func:`g2o_text_lines` give them), ``id_i`` and ``id_j`` its
    vertex ids, in the order of ``indices``. One comment line opens the list: ``# <title>:``
    and the format. Lines that start with ``#`` are comments; every other line has those
    five fields.

    Raises:
        OutputError: an index that is not an edge with a line.
    """
    return _edge_list_text(graph, indices, lines, title, g2o_name, _graph_format(graph))
