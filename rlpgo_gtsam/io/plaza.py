"""The CMU ranging-radio logs (Plaza1, Plaza2: Djugash, Hamner and Roth, "Navigating with
Ranging Radios: Five Data Sets with Ground Truth", 2009) as the range-aided GTSAM graph that
GTSAM's ``RangeISAMExample_plaza2`` builds; GTSAM's wheel ships both (``Plaza1_DR.txt``,
``Plaza1_TD.txt``, ``Plaza2_DR.txt``, ``Plaza2_TD.txt``: ``gtsam.findExampleDataFile``).

Two text files, whitespace-separated numbers, one record a line:

- dead reckoning (``*_DR.txt``): ``time distance_travelled delta_heading`` (s, m, rad), the
  step since the previous line;
- ranges (``*_TD.txt``): ``time sender receiver range`` (s, ids, m): the vehicle's radio
  (sender) measured its distance to the beacon ``receiver``.

The graph, as the example builds it (:class:`PlazaSettings` holds its constants):

- pose 0 (key 0) at the example's start, with a ``PriorFactorPose2`` of sigmas (1 m, 1 m,
  pi rad): it fixes the frame and barely anything else;
- pose ``i`` (key ``i``) after the ``i``-th dead-reckoning line, a ``BetweenFactorPose2(i - 1,
  i, Pose2(distance, 0, delta_heading))`` with diagonal sigmas (0.05 m, 0.01 m, 0.1 rad); the
  initial values chain these steps from pose 0;
- each range a ``RangeFactor2D(i, symbol('L', receiver), range)`` with
  ``Isotropic.Sigma(1, 100 m)``, ``i`` the first pose whose dead-reckoning time is at or after
  the range's (the example's loop adds the ranges up to each step's time to that step's pose);
  ranges after the last dead-reckoning line are left out, as the example's loop never reaches
  them.

Where this differs from the example, and why: the example wraps the range noise in a Tukey
M-estimator (width 15), which the relaxation cannot model (it would be carried to LM):
``robust_ranges=True`` does as the example, the default keeps the Gaussian it wraps. The
example pairs ranges with poses in file order, which on Plaza1 (two range lines earlier than
the line before them, by 64 and 50 s) moves 217 ranges up to a minute later; here each range
goes by its own time. The example starts the beacons at random points with a loose prior on
each, which an incremental solver needs for a beacon's first few ranges; here each beacon
starts at the centroid of the initial positions of the poses that range to it (what
:func:`~rlpgo_gtsam.synthetic.generate_ranges` does), and every beacon is ranged hundreds of
times, so no prior is added.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError
from rlpgo_gtsam.io.lines import numbered_lines, parse_numbers

__all__ = ["PlazaSettings", "read_plaza", "PLAZA_FIRST_POSE"]

# GTSAM's RangeISAMExample_plaza2 (and SmartRangeExample_plaza1, for Plaza1) start here
PLAZA_FIRST_POSE = (-34.2086489999201, 45.3007639991120, math.pi - 2.021089)


@dataclass(frozen=True)
class PlazaSettings:
    """The constants of the graph :func:`read_plaza` builds: those of GTSAM's
    ``RangeISAMExample_plaza2``."""

    first_pose: tuple[float, float, float] = PLAZA_FIRST_POSE
    """Pose 0: x (m), y (m), heading (rad)."""
    prior_sigmas: tuple[float, float, float] = (1.0, 1.0, math.pi)
    """Standard deviations of the prior on pose 0: x, y (m), heading (rad)."""
    odometry_sigmas: tuple[float, float, float] = (0.05, 0.01, 0.1)
    """Standard deviations of each dead-reckoning step: along, across (m), heading (rad)."""
    sigma_range_m: float = 100.0
    """Standard deviation of a range, metres."""
    robust_ranges: bool = False
    """Wrap the range noise in a Tukey M-estimator of width 15, as the example does (the
    relaxation then leaves the ranges to LM)."""


def read_plaza(dr_path: str | os.PathLike[str], td_path: str | os.PathLike[str],
               settings: PlazaSettings | None = None
               ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a dead-reckoning file and a range file of the Plaza logs into a GTSAM graph and
    initial values (see the module docstring).

    Raises:
        G2oFormatError: a file missing, unreadable or malformed: a line without its numbers,
            a dead-reckoning time that does not increase, a beacon id that is not a
            non-negative integer, a negative range (``file:line: reason``).
    """
    settings = settings or PlazaSettings()
    dr_path, td_path = Path(dr_path), Path(td_path)
    steps = _rows(dr_path, "dead reckoning", 3)
    ranges = _rows(td_path, "range", 4)
    for (line, row), (_, before) in zip(steps[1:], steps[:-1], strict=True):
        if not row[0] > before[0]:
            raise G2oFormatError(dr_path, line, f"time {row[0]!r} s does not follow the line "
                                 f"before ({before[0]!r} s)")
    times = np.array([row[0] for _, row in steps])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose = gtsam.Pose2(*settings.first_pose)
    graph.add(gtsam.PriorFactorPose2(0, pose, gtsam.noiseModel.Diagonal.Sigmas(
        np.array(settings.prior_sigmas))))
    values.insert(0, pose)
    odometry = gtsam.noiseModel.Diagonal.Sigmas(np.array(settings.odometry_sigmas))
    for i, (_, (_, distance, heading)) in enumerate(steps, start=1):
        step = gtsam.Pose2(distance, 0.0, heading)
        graph.add(gtsam.BetweenFactorPose2(i - 1, i, step, odometry))
        pose = pose.compose(step)
        values.insert(i, pose)
    noise: gtsam.noiseModel.Base = gtsam.noiseModel.Isotropic.Sigma(1, settings.sigma_range_m)
    if settings.robust_ranges:
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Tukey.Create(15.0),
                                               noise)
    rangers: dict[int, list[int]] = {}
    for line, (time, _, receiver, measured) in ranges:
        if receiver < 0 or receiver != int(receiver) or receiver >= 2**56:
            raise G2oFormatError(td_path, line, f"beacon id {receiver!r} is not a "
                                 "non-negative integer")
        if measured < 0:
            raise G2oFormatError(td_path, line, f"range must be >= 0, found {measured!r}")
        ranger = int(np.searchsorted(times, time, side="left")) + 1
        if ranger > len(times):  # after the last dead-reckoning line
            continue
        beacon = int(gtsam.symbol("L", int(receiver)))
        graph.add(gtsam.RangeFactor2D(ranger, beacon, measured, noise))
        rangers.setdefault(beacon, []).append(ranger)
    for beacon, poses in sorted(rangers.items()):
        positions = np.array([values.atPose2(i).translation() for i in poses])
        values.insert(beacon, gtsam.Point2(*positions.mean(axis=0)))
    return graph, values


def _rows(path: Path, what: str, count: int) -> list[tuple[int, list[float]]]:
    """(line, numbers) of each non-blank line of ``path``, each with ``count`` numbers."""
    rows = []
    for line, text in numbered_lines(path, kind=f"Plaza {what}"):
        fields = text.split()
        if not fields:
            continue
        if len(fields) != count:
            raise G2oFormatError(path, line, f"a {what} line holds {count} numbers, found "
                                 f"{len(fields)}")
        rows.append((line, parse_numbers(path, line, what, fields, 1)))
    if not rows:
        raise G2oFormatError(path, None, f"holds no {what} line")
    return rows
