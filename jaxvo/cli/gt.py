"""``jaxvo gt``: a sequence's ground truth as camera poses, for other tools (evo)."""
from __future__ import annotations

from pathlib import Path

import click

from jaxvo.camera import DEFAULT
from jaxvo.cli.options import CONVENTIONS, FORCE
from jaxvo.cli.process import handle_errors
from jaxvo.data import DatasetError
from jaxvo.data.outputs import check_output

__all__ = ["gt_cmd"]


@click.command("gt", help=f"""Write a sequence's ground truth as camera poses, for other tools (evo).

SEQUENCE_DIR is any folder jaxvo run reads. The ground truth (groundtruth.txt, or ICL-NUIM's
*.gt.freiburg) is written to --out as a TUM trajectory of camera poses T_world_cam; for Bonn
RGB-D Dynamic folders (rgbd_bonn_*) the motion-capture marker poses are converted to camera
poses first, as jaxvo eval does. Then evo gives jaxvo eval's numbers:

\b
  jaxvo gt SEQ -o gt.txt
  evo_ape tum gt.txt traj.txt -a --t_max_diff 0.02                          # ATE
  evo_rpe tum gt.txt traj.txt --delta 1 --delta_unit f --t_max_diff 0.02     # RPE 1 frame
  evo_rpe tum gt.txt traj.txt --delta 1 --delta_unit f --t_max_diff 0.02 --pose_relation angle_deg

{CONVENTIONS}
""")
@click.argument("sequence_dir", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="TUM trajectory file to write (camera poses T_world_cam).")
@click.option("--bonn/--no-bonn", default=None,
              help="Force / forbid the Bonn marker-to-camera conversion. [default: by folder name]")
@FORCE
@handle_errors
def gt_cmd(sequence_dir, out, bonn, force):
    from jaxvo.data import open_sequence
    from jaxvo.data.trajectory import HEADER, write_tum_trajectory

    check_output(out, [sequence_dir], force, "--out")
    seq = open_sequence(sequence_dir, bonn=bonn, camera=DEFAULT)  # intrinsics are not needed here
    check_output(out, [sequence_dir, seq.groundtruth_path], force, "--out")
    gt = seq.groundtruth
    if gt is None:
        raise DatasetError(f"{seq.groundtruth_path}: file not found (the sequence folder has no ground truth)")
    what = "Bonn marker poses converted to camera poses" if seq.is_bonn else "as stored"
    write_tum_trajectory(out, gt[0], gt[1], header=f"# ground truth of {seq.path} ({seq.groundtruth_path.name}, "
                                                    f"{what})\n{HEADER}")
    click.echo(f"wrote {len(gt[0])} ground-truth camera poses ({what}) to {out}")
