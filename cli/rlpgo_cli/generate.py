"""rlpgo-generate: write one of the paper's synthetic lawn-mower pose graphs as g2o (planar,
or its layers in 3D with ``--dim 3``), with points measured by bearing and range with
``--landmarks N``, or as PyFG (an output ending in ``.pyfg``), with ranges to beacons and
between poses with ``--ranges N`` / ``--pose-ranges K`` (in 3D along a climbing helix)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.formats import PYFG, graph_text, is_pyfg
from rlpgo_cli.output import RunFiles
from rlpgo_cli.types import SEED, FiniteFloat, OutputFile
from rlpgo_gtsam.graph import chi2
from rlpgo_gtsam.groups import SE2, SE3
from rlpgo_gtsam.io import EDGE_LIST_LINE, edge_list_text, g2o_text_lines
from rlpgo_gtsam.landmarks import RANGE_FACTORS
from rlpgo_gtsam.synthetic import (
    GROUP_SIZE,
    LAYER_ROWS,
    LOCAL_RANGE,
    MIN_BEACON_RANGES,
    OUTLIER_MODES,
    ROW_LENGTH,
    LandmarkSettings,
    RangeSettings,
    generate,
    generate_helix_ranges,
    generate_landmarks,
    generate_ranges,
)

# --dim: the pose group
_GROUPS = {2: SE2, 3: SE3}
# options of the landmarks' bearings alone, refused without --landmarks
_LANDMARK_OPTIONS = ("sigma_bearing", "max_sightings")
# options of the range sensor, which landmarks and ranges share: refused without either
_SENSOR_OPTIONS = ("sensor_range", "sigma_range")
# options of the planar lawn mower that the 3D range graph (a helix) has no use for
_HELIX_REFUSED = ("d", "lc", "sensor_range")


@click.command(cls=RlpgoCommand)
@click.option("--dim", type=click.IntRange(2, 3), default=2, show_default=True,
              help=f"2: the planar lawn mower (EDGE_SE2); 3: the lawn mower in layers of "
                   f"{LAYER_ROWS} rows of {ROW_LENGTH}, d apart, with loop closures to the "
                   "poses beside and under each pose (EDGE_SE3:QUAT, VERTEX_SE3:QUAT).")
@click.option("--n", type=click.IntRange(2, 1_000_000), default=300, show_default=True,
              help="Number of poses (a million take minutes and about 1.5 GB).")
@click.option("--sigma-r", type=FiniteFloat(1e-9, 3.2), default=0.3,
              show_default=True, help="Rotation noise, radians (per axis in 3D).")
@click.option("--sigma-t", type=FiniteFloat(1e-9, 1e6), default=0.05,
              show_default=True, help="Translation noise per axis, metres.")
@click.option("--d", type=FiniteFloat(1e-6, 1e6), default=3.0,
              show_default=True, help="Spacing of poses, rows and layers, metres.")
@click.option("--lc", type=FiniteFloat(0.0, 1.0), default=0.5, show_default=True,
              help="Fraction of loop-closure candidates kept.")
@click.option("--noisy-measurements", is_flag=True,
              help="Perturb the measurements too (the paper's graphs have exact ones).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Random seed.")
@click.option("-o", "--output", type=OutputFile(), required=True,
              help="File for the graph and its noisy initial guess: PyFG if its name ends in "
                   ".pyfg (planar or 3D), else g2o.")
@click.option("--ground-truth", type=OutputFile(),
              help="File for the graph with the ground-truth poses (PyFG or g2o, by its name "
                   "as OUTPUT).")
@click.option("--outliers", type=FiniteFloat(0.0, 1.0, max_open=True), default=0.0,
              show_default=True,
              help="Wrong loop closures to add, as a fraction of the graph's edges.")
@click.option("--outlier-mode", type=click.Choice(OUTLIER_MODES), default=OUTLIER_MODES[0],
              show_default=True,
              help="Vertigo's policies (each measures a small relative pose, N(0, 0.3 m), "
                   "N(0, 10 deg), with the first loop closure's information): random: random "
                   f"pose pairs; local: the second pose within {LOCAL_RANGE} of the first; "
                   "group: --group-size consecutive pairs (i+k, j+k) sharing one measurement; "
                   "localgroup: local groups. Also: uniform: random pairs with "
                   "random relative poses; plausible: far-apart poses measured like a true "
                   "closure.")
@click.option("--group-size", type=click.IntRange(1, 10_000), default=GROUP_SIZE,
              show_default=True, help="Wrong closures per group (group, localgroup).")
@click.option("--outliers-out", type=OutputFile(),
              help=f"Text file listing the wrong loop closures, one a line as "
                   f"'{EDGE_LIST_LINE}' (EDGE_SE3:QUAT with --dim 3; L: the edge's line in "
                   "OUTPUT, from 1), after one '#' line: the format of rlpgo-init "
                   "--outliers-out.")
@click.option("--landmarks", type=click.IntRange(0, 1_000_000), default=0, show_default=True,
              help="Points to place near the path (in the plane; in space with --dim 3), "
                   "each measured by bearing and range from every pose within "
                   "--sensor-range (EDGE_SE2_XY, VERTEX_XY; EDGE_SE3_TRACKXYZ, "
                   "VERTEX_TRACKXYZ); points no pose sees are dropped. 0: a pose graph.")
@click.option("--ranges", type=click.IntRange(0, 1_000_000), default=0, show_default=True,
              help="Beacons to place in the path's bounding box grown by "
                   f"{RangeSettings.margin_m:g} m, each ranged from every pose within "
                   "--sensor-range (EDGE_RANGE to VERTEX_XY lines; at least "
                   f"{MIN_BEACON_RANGES} poses each): a range-aided graph, written as PyFG "
                   f"(OUTPUT must end in {PYFG}). With --dim 3: a climbing helix of 1 m steps "
                   "(odometry noise --sigma-r, --sigma-t; a prior on the first pose), every "
                   "second pose ranging each beacon, placed in a 12 m cube (VERTEX_XYZ); "
                   "--d, --lc and --sensor-range do not apply.")
@click.option("--pose-ranges", type=click.IntRange(0, 1_000_000), default=0,
              show_default=True,
              help="Ranges between pairs of poses within --sensor-range (EDGE_RANGE between "
                   "VERTEX_SE2 lines; with --dim 3 between random pairs of poses), with or "
                   "without --ranges; written as PyFG.")
@click.option("--sensor-range", type=FiniteFloat(1e-6, 1e6),
              default=LandmarkSettings.sensor_range_m, show_default=True,
              help="The farthest a pose measures a point (--landmarks) or a range (--ranges, "
                   "--pose-ranges), metres.")
@click.option("--sigma-bearing", type=FiniteFloat(1e-9, 3.2),
              default=LandmarkSettings.sigma_bearing_rad, show_default=True,
              help="Bearing noise, radians (per tangent axis in 3D).")
@click.option("--sigma-range", type=FiniteFloat(1e-9, 1e6),
              default=LandmarkSettings.sigma_range_m, show_default=True,
              help="Range noise, metres (--landmarks, --ranges, --pose-ranges).")
@click.option("--max-sightings", type=click.IntRange(1, 1_000_000),
              help="Measure only the nearest this many points from each pose (default: "
                   "every point in range).")
@click.pass_context
def main(ctx, dim, n, sigma_r, sigma_t, d, lc, noisy_measurements, seed, output, ground_truth,
         outliers, outlier_mode, group_size, outliers_out, landmarks, ranges, pose_ranges,
         sensor_range, sigma_bearing, sigma_range, max_sightings):
    """Generate a lawn-mower pose graph as in the RL-PGO paper (in layers in 3D: --dim 3),
    with points measured by bearing and range with --landmarks N, or ranges to beacons and
    between poses with --ranges N / --pose-ranges K (written as PyFG: CORA's problem; in 3D
    along a climbing helix)."""
    ranging = ranges > 0 or pose_ranges > 0
    _check_landmark_options(ctx, landmarks, ranging, outliers, outliers_out)
    _check_formats(ctx, dim, ranging, output, ground_truth, outliers_out)
    run = RunFiles()
    run.check(output, ground_truth, outliers_out)
    rng = np.random.default_rng(seed)
    if ranging and dim == 3:
        sample = generate_helix_ranges(n, rng, beacons=ranges, pose_ranges=pose_ranges,
                                       noise=1.0 if noisy_measurements else 0.0,
                                       rotation_sigma=sigma_r, translation_sigma=sigma_t,
                                       sigma_range_m=sigma_range)
    elif ranging:
        sample = generate_ranges(n, sigma_r, sigma_t, d, lc, rng,
                                 RangeSettings(ranges, pose_ranges, sigma_range, sensor_range),
                                 noisy_measurements=noisy_measurements)
    elif landmarks > 0:
        settings = LandmarkSettings(landmarks, sensor_range, sigma_bearing, sigma_range,
                                    max_sightings)
        sample = generate_landmarks(n, sigma_r, sigma_t, d, lc, rng, settings,
                                    noisy_measurements=noisy_measurements, group=_GROUPS[dim])
    else:
        sample = generate(n, sigma_r, sigma_t, d, lc, rng,
                          noisy_measurements=noisy_measurements, outliers=outliers,
                          outlier_mode=outlier_mode, group_size=group_size, group=_GROUPS[dim])
    if is_pyfg(output):
        text, lines = graph_text(output, sample.graph, sample.initial), []
    else:
        text, lines = g2o_text_lines(sample.graph, sample.initial)
    files = [(output, text.encode())]
    if ground_truth is not None:
        files.append((ground_truth,
                      graph_text(ground_truth, sample.graph, sample.ground_truth).encode()))
    if outliers_out is not None:
        listed = edge_list_text(sample.graph, sample.outlier_edges, lines, g2o_name=output.name,
                                title="wrong loop closures that rlpgo-generate added")
        files.append((outliers_out, listed.encode("utf-8", "surrogateescape")))
    run.write_together(files)  # every file or none
    points = f"{sample.num_landmarks} landmarks, " if landmarks > 0 else ""
    if ranging:
        measured = sum(isinstance(sample.graph.at(k), RANGE_FACTORS)
                       for k in range(sample.graph.size()))
        points = f"{sample.num_landmarks} beacons, {measured} ranges, "
    click.echo(f"{output}: {n} poses, {points}{sample.graph.size()} edges, initial chi2 "
               f"{chi2(sample.graph, sample.initial):.6g}, ground-truth chi2 "
               f"{chi2(sample.graph, sample.ground_truth):.6g}")
    if outliers > 0 or outliers_out is not None:
        listed = "" if outliers_out is None else f"; listed in {outliers_out}"
        grouped = f", groups of {group_size}" if "group" in outlier_mode else ""
        click.echo(f"added {len(sample.outlier_edges)} wrong loop closures ({outlier_mode}"
                   f"{grouped})"
                   f"{listed}")


def _check_landmark_options(ctx: click.Context, landmarks: int, ranging: bool,
                            outliers: float, outliers_out: Path | None) -> None:
    """Usage errors for landmark options without --landmarks, sensor options without
    landmarks or ranges, ranges with landmarks or their options, and wrong loop closures
    with either (the generator adds them to pose graphs only)."""
    landmark_options, sensor_options = _given(ctx, _LANDMARK_OPTIONS), _given(ctx, _SENSOR_OPTIONS)
    if ranging:
        refused = (["--landmarks"] if landmarks > 0 else []) + landmark_options
        if outliers > 0 or outliers_out is not None:
            refused.append("--outliers" if outliers > 0 else "--outliers-out")
        if refused:
            raise click.UsageError(f"{', '.join(refused)}: not used with --ranges or "
                                   "--pose-ranges (a range-aided graph has no bearings, "
                                   "landmarks seen by bearing or wrong loop closures)")
        return
    if landmarks == 0:
        if landmark_options:
            raise click.UsageError(f"{', '.join(landmark_options)}: options of the "
                                   "landmarks; give --landmarks N too")
        if sensor_options:
            raise click.UsageError(f"{', '.join(sensor_options)}: options of the "
                                   "landmarks and the ranges; give --landmarks N, --ranges N "
                                   "or --pose-ranges K too")
    elif outliers > 0 or outliers_out is not None:
        raise click.UsageError("--outliers and --outliers-out make pose graphs; they do not "
                               "combine with --landmarks")


def _given(ctx: click.Context, names: tuple[str, ...]) -> list[str]:
    """The options among ``names`` that the user gave (not left at their defaults), as
    ``--name``."""
    unset = (None, click.core.ParameterSource.DEFAULT, click.core.ParameterSource.DEFAULT_MAP)
    return [f"--{name.replace('_', '-')}" for name in names
            if ctx.get_parameter_source(name) not in unset]


def _check_formats(ctx: click.Context, dim: int, ranging: bool, output: Path,
                   ground_truth: Path | None, outliers_out: Path | None) -> None:
    """Usage errors for outputs whose format cannot hold the graph and options the graph has
    no use for: ranges outside PyFG (g2o has no range line), the planar lawn mower's
    spacing, loop closures and sensor range beside 3D ranges (a helix), a list of g2o lines
    beside a PyFG output."""
    outputs = [path for path in (output, ground_truth) if path is not None]
    if ranging:
        unused = _given(ctx, _HELIX_REFUSED) if dim == 3 else []
        if unused:
            raise click.UsageError(f"{', '.join(unused)}: not used by the 3D range graph (a "
                                   "helix of 1 m steps without loop closures, every second "
                                   "pose ranging each beacon)")
        not_pyfg = [str(path) for path in outputs if not is_pyfg(path)]
        if not_pyfg:
            raise click.UsageError(f"{', '.join(not_pyfg)}: a graph with ranges is written as "
                                   f"PyFG (g2o has no range line); give a name ending in {PYFG}")
    if outliers_out is not None and is_pyfg(output):
        raise click.UsageError("--outliers-out lists edges by their g2o lines; OUTPUT is a "
                               "PyFG file")


if __name__ == "__main__":
    main()
