"""rlpgo-example: the pose graphs GTSAM's wheel ships; with NAME, that file's path."""

from __future__ import annotations

import click

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_gtsam.datasets import EXAMPLES, example_file, example_names

_KIND = {2: "planar", 3: "3D"}


@click.command(cls=RlpgoCommand)
@click.argument("name", required=False)
def main(name):
    """Print the path of GTSAM's example data file NAME (as gtsam.findExampleDataFile finds
    it), for the other commands: rlpgo-init "$(rlpgo-example pose2example.txt)" -o OUT.
    Without NAME, list the pose graphs of GTSAM's data that the commands read."""
    if name is not None:
        click.echo(example_file(name))
        return
    present = set(example_names())
    click.echo(f"{'name':<34} {'graph':<6} {'poses':>5} {'edges':>5}  about")
    for example in EXAMPLES:
        if example.name in present:
            click.echo(f"{example.name:<34} {_KIND[example.dimension]:<6} {example.poses:>5} "
                       f"{example.edges:>5}  {example.about}")
