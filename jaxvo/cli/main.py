"""The ``jaxvo`` command line: ``run``, ``eval``, ``gt``, ``synth``, ``augment``, ``demo``, ``map``, ``masks``.

This module is the command group; each command lives in its own module of :mod:`jaxvo.cli`
(options, one :mod:`jaxvo.pipelines` call, printing), and process, signal and exit handling in
:mod:`jaxvo.cli.process`. Every command reports bad input (missing or malformed files,
undecodable images, a depth image that is not 16-bit, no colour/depth association, ground
truth that does not cover the sequence, ...) as one line ``error: <file>: <problem>`` on stderr
and exit code 2, never a traceback.
"""
from __future__ import annotations

import click

from jaxvo.cli.augment import augment_cmd
from jaxvo.cli.demo import demo_cmd
from jaxvo.cli.eval import eval_cmd
from jaxvo.cli.gt import gt_cmd
from jaxvo.cli.map import map_cmd
from jaxvo.cli.masks import masks_cmd
from jaxvo.cli.options import CONVENTIONS
from jaxvo.cli.process import Group, entry
from jaxvo.cli.run import run_cmd
from jaxvo.cli.synth import synth_cmd

__all__ = ["main", "entry"]


@click.group(cls=Group, help=f"""jaxvo: robust dense RGB-D visual odometry (classic, Huber and RANSAC) in JAX.

\b
  jaxvo demo                          # synthetic dynamic scene, all three methods, figures
  jaxvo run SEQ --out traj.txt        # track a TUM-layout sequence folder
  jaxvo eval SEQ traj.txt             # RPE / ATE against the sequence's ground truth
  jaxvo synth seq2 OUT                # write a synthetic sequence (TUM layout + masks/)
  jaxvo augment REAL_SEQ OUT          # add synthetic moving persons to a real sequence
  jaxvo map SEQ traj.txt map.ply      # coloured 3-D point cloud (moving points green)
  jaxvo masks SEQ traj.txt OUT        # moving-pixel masks in hindsight (earlier and later frames)
  jaxvo gt SEQ -o gt.txt              # ground truth as camera poses (for evo)

{CONVENTIONS}
""")
@click.version_option(package_name="jaxvo", prog_name="jaxvo")
def main():
    pass


for _command in (run_cmd, eval_cmd, gt_cmd, synth_cmd, augment_cmd, demo_cmd, map_cmd, masks_cmd):
    main.add_command(_command)


if __name__ == "__main__":  # pragma: no cover
    main()
