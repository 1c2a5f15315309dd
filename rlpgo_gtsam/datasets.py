"""The example graphs GTSAM's Python wheel ships, by name: pose graphs, landmark graphs and
range-aided graphs.

The gtsam wheel carries its example data (``gtsam/Data``), found by
``gtsam.findExampleDataFile``. :func:`example_file` resolves a name there as that function
does (``"pose2example.txt"``, or ``"pose2example"`` without its extension), so that the
README's first commands run from a fresh clone with nothing beside it.
:data:`EXAMPLES` lists the files of that folder that this package's readers take (g2o's
pose and landmark lines, CORA's PyFG); the folder's other files are TORO graphs
(``VERTEX2``/``EDGE2``, ``EDGE3``: their information matrices are laid out differently from
file to file, so the reader refuses them with its ``file:line``) and other data.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rlpgo_gtsam.errors import InputNotFoundError

__all__ = ["Example", "EXAMPLES", "example_file", "example_names"]


@dataclass(frozen=True)
class Example:
    """One graph of GTSAM's example data.

    Attributes:
        name: the file's name in GTSAM's data folder.
        dimension: 2 (``Pose2``) or 3 (``Pose3``).
        poses: vertices the file defines.
        edges: its between factors.
        about: what it is, in a few words.
        points: its landmarks or beacons.
        measurements: their sightings or ranges.
        certified: whether the default certifies it (range-aided graphs: not)
    """

    name: str
    dimension: int
    poses: int
    edges: int
    about: str
    points: int = 0
    measurements: int = 0
    certified: bool = True


EXAMPLES: tuple[Example, ...] = (
    Example("noisyToyGraph.txt", 2, 4, 5, "GTSAM's Pose2SLAMExample_g2o input"),
    Example("pose2example.txt", 2, 11, 12, "a planar loop"),
    Example("pose3example.txt", 3, 5, 6, "GTSAM's Pose3SLAMExample_g2o input"),
    Example("pose3example-grid.txt", 3, 27, 44, "a walk through a 3 x 3 x 3 grid"),
    Example("toyExample.g2o", 3, 5, 6, "a small loop, every guess at the origin"),
    Example("simpleGraph10gradIter.txt", 3, 5, 6, "toyExample.g2o's graph, another guess"),
    Example("Klaus3.g2o", 3, 3, 3, "three poses, a triangle"),
    Example("victoriaPark_reduced_1k.g2o", 2, 1000, 999,
            "Victoria Park: 48 trees seen 606 times (LANDMARK2)", 48, 606),
    Example("cityTrees_reduced_1k.g2o", 2, 1000, 999,
            "simulated city trees: 66 seen 406 times (LANDMARK2)", 66, 406),
    Example("goats_16.pyfg", 2, 201, 200, "CORA's goats: 4 beacons, 572 ranges (PyFG)", 4, 572,
            False),
    Example("goats_15.pyfg", 2, 473, 472, "CORA's goats: 3 beacons, 786 ranges (PyFG)", 3, 786,
            False),
    Example("known_landmark_localization_20.g2o", 3, 20, 19,
            "4 points seen 80 times (EDGE_SE3_TRACKXYZ)", 4, 80),
)


def _find(name: str) -> Path | None:
    """GTSAM's example file ``name`` (one file name, no folder), or None."""
    if not name or name in (".", "..") or any(c in name for c in "/\\\0"):
        return None  # findExampleDataFile would join a path outside its folder
    from gtsam.utils import findExampleDataFile

    try:
        found = Path(findExampleDataFile(name))
    except (FileNotFoundError, RuntimeError, ValueError):
        return None
    return found if found.is_file() else None


def example_names(dimension: int | None = None) -> list[str]:
    """The names of :data:`EXAMPLES` this installation of GTSAM holds, planar first;
    ``dimension`` 2 or 3: that dimension's only."""
    if dimension not in (None, 2, 3):
        raise ValueError(f"dimension must be 2, 3 or None, not {dimension!r}")
    return [example.name for example in EXAMPLES
            if dimension in (None, example.dimension) and _find(example.name) is not None]


def example_file(name: str) -> str:
    """The path of GTSAM's example data file ``name``, as ``gtsam.findExampleDataFile``
    finds it: ``example_file("pose2example.txt")`` (or ``"pose2example"``).

    Raises:
        InputNotFoundError: GTSAM's data holds no file ``name``; the message lists the
            pose graphs it holds (:func:`example_names`).
    """
    if not isinstance(name, str):
        raise TypeError(f"example_file takes a file name (str), not {type(name).__name__}")
    found = _find(name)
    if found is None:
        planar, spatial = example_names(2), example_names(3)
        raise InputNotFoundError(name or "''", "not in GTSAM's example data; its pose graphs: "
                                 f"{', '.join(planar)} (planar); {', '.join(spatial)} (3D)")
    return str(found)
