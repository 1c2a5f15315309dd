"""rlpgo-generate: write one of the paper's synthetic lawn-mower pose graphs as g2o."""

from __future__ import annotations

import click
import numpy as np

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.output import RunFiles
from rlpgo_cli.types import SEED, FiniteFloat, OutputFile
from rlpgo_gtsam.files import write_together
from rlpgo_gtsam.g2o import g2o_text
from rlpgo_gtsam.graph import chi2
from rlpgo_gtsam.synthetic import generate


@click.command(cls=RlpgoCommand)
@click.option("--n", type=click.IntRange(2, 1_000_000), default=300, show_default=True,
              help="Number of poses (a million take minutes and about 1.5 GB).")
@click.option("--sigma-r", type=FiniteFloat(1e-9, 3.2), default=0.3,
              show_default=True, help="Rotation noise, radians.")
@click.option("--sigma-t", type=FiniteFloat(1e-9, 1e6), default=0.05,
              show_default=True, help="Translation noise per axis, metres.")
@click.option("--d", type=FiniteFloat(1e-6, 1e6), default=3.0,
              show_default=True, help="Spacing of poses and rows, metres.")
@click.option("--lc", type=FiniteFloat(0.0, 1.0), default=0.5, show_default=True,
              help="Fraction of loop-closure candidates kept.")
@click.option("--noisy-measurements", is_flag=True,
              help="Perturb the measurements too (the paper's graphs have exact ones).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Random seed.")
@click.option("-o", "--output", type=OutputFile(), required=True,
              help="g2o file for the graph and its noisy initial guess.")
@click.option("--ground-truth", type=OutputFile(),
              help="g2o file for the graph with the ground-truth poses.")
def main(n, sigma_r, sigma_t, d, lc, noisy_measurements, seed, output, ground_truth):
    """Generate a lawn-mower pose graph as in the RL-PGO paper."""
    run = RunFiles()
    run.check(output, ground_truth)
    sample = generate(n, sigma_r, sigma_t, d, lc, np.random.default_rng(seed),
                      noisy_measurements=noisy_measurements)
    files = [(output, g2o_text(sample.graph, sample.initial).encode())]
    if ground_truth is not None:
        files.append((ground_truth, g2o_text(sample.graph, sample.ground_truth).encode()))
    write_together(files)  # both files or neither
    click.echo(f"{output}: {n} poses, {sample.graph.size()} edges, initial chi2 "
               f"{chi2(sample.graph, sample.initial):.6g}, ground-truth chi2 "
               f"{chi2(sample.graph, sample.ground_truth):.6g}")


if __name__ == "__main__":
    main()
