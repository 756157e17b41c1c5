"""``jaxvo eval``: a trajectory against ground truth: RPE, ATE, mask scores; JSON and a figure."""
from __future__ import annotations

import json
from pathlib import Path

import click

from jaxvo.cli.options import CONVENTIONS, FORCE, POSITIVE, scale_text
from jaxvo.cli.process import handle_errors
from jaxvo.data.outputs import check_output, write_text, writing
from jaxvo.data import DatasetError
from jaxvo.evaluation.scoring import evaluate
from jaxvo.pipelines.demo import fmt
from jaxvo.pipelines.messages import one_line

__all__ = ["eval_cmd"]


@click.command("eval", help=f"""Compare a trajectory with ground truth: RPE, ATE, mask scores.

GROUNDTRUTH is a TUM ground-truth file or a sequence folder (its groundtruth.txt is used;
for Bonn RGB-D Dynamic folders, rgbd_bonn_*, the motion-capture marker poses are converted
to camera poses). EST is a TUM trajectory file (e.g. from jaxvo run).

Prints a table of the relative pose error for pairs of estimate frames DELTA apart
(translation in m, rotation in deg; per second with --delta-unit s, per frame with f;
rmse, mean, median, max and the number of pairs) and the absolute trajectory error (m,
after the least-squares rigid alignment of the estimate to the ground truth), then the scale
of the least-squares similarity alignment: 1 for a metric trajectory, and a few per cent off
where the recording's depth reads too far or too near (see jaxvo run --depth-scale). With --delta
and --delta-unit left at their defaults, an estimate shorter than 1 s is measured over 1
frame instead, with a note (as jaxvo run does). Poses are
associated by timestamp (nearest, within --max-dt s); ground truth that does not cover the
estimate is an error.

With --masks-dir (the folder written by jaxvo run --save-masks) and a GROUNDTRUTH folder
holding the true moving-pixel masks (masks/, as jaxvo synth and jaxvo augment write), also
the outlier mask's precision, recall and IoU (the moving class is the positive one),
pooled over all frames matched by timestamp.

--plot writes a figure: top view of the ground truth and the aligned estimate, and the
translational drift (RPE per pair) and ATE per frame over time.

{CONVENTIONS}
""")
@click.argument("groundtruth", type=click.Path(path_type=Path))
@click.argument("est", type=click.Path(path_type=Path))
@click.option("--delta", type=POSITIVE, default=1.0, show_default=True, help="RPE pair spacing (see --delta-unit).")
@click.option("--delta-unit", type=click.Choice(["s", "f"]), default="s", show_default=True,
              help="s = seconds (drift in m/s and deg/s, the paper's Table I), f = frames.")
@click.option("--max-dt", type=POSITIVE, default=0.02, show_default=True,
              help="Maximum estimate/ground-truth timestamp difference, seconds.")
@click.option("--json", "json_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the results as JSON.")
@click.option("--plot", "plot_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the trajectory / drift figure (PNG, PDF, SVG by extension).")
@click.option("--masks-dir", type=click.Path(path_type=Path), default=None,
              help="Outlier masks saved by 'jaxvo run --save-masks' to score against the true masks.")
@click.option("--bonn/--no-bonn", default=None,
              help="Force / forbid the Bonn marker-to-camera ground-truth conversion. [default: by folder name]")
@click.option("--per-pair", is_flag=True, help="Include per-pair errors in the JSON output.")
@FORCE
@handle_errors
def eval_cmd(groundtruth, est, delta, delta_unit, max_dt, json_file, plot_file, masks_dir, bonn, per_pair, force):
    for out, opt in ((json_file, "--json"), (plot_file, "--plot")):
        if out is not None:
            check_output(out, [groundtruth, est, masks_dir], force, opt)
    ctx = click.get_current_context()
    defaults = all(ctx.get_parameter_source(p) == click.core.ParameterSource.DEFAULT for p in ("delta", "delta_unit"))
    res = evaluate(groundtruth, est, delta, delta_unit, max_dt, masks_dir, bonn, short_frames=defaults)
    if (res.delta, res.delta_unit) != (delta, delta_unit):
        es = res.est[0]
        click.echo(f"note: {est} spans {es[-1] - es[0]:.2f} s, less than the default RPE delta of {delta:g} s: "
                   f"RPE over 1 frame instead")
        delta, delta_unit = res.delta, res.delta_unit
    r, a, m = res.rpe, res.ate, res.masks
    u = "s" if delta_unit == "s" else "frame"
    dl = f"{delta:g} {'s' if delta_unit == 's' else 'frame(s)'}"
    rows = [(f"RPE trans [m/{u}]", r.trans_drift), (f"RPE rot [deg/{u}]", r.rot_drift), ("ATE [m]", a.stats)]
    lines = [f"ground truth {res.gt_file}", f"estimate     {est}  ({res.est[0].size} poses)",
             f"RPE delta {dl}, ATE after rigid alignment", "",
             f"{'':<20}{'rmse':>10}{'mean':>10}{'median':>10}{'max':>10}{'n':>7}"]
    for name, s in rows:
        nd = 3 if "deg" in name else 4
        lines.append(f"{name:<20}{fmt(s.rmse, nd):>10}{fmt(s.mean, nd):>10}{fmt(s.median, nd):>10}"
                     f"{fmt(s.max, nd):>10}{s.n:>7}")
    lines.append(scale_text(a.scale, 4, " (similarity alignment; 1 for a metric trajectory)"))
    if m is not None:
        lines += ["", f"outlier mask vs true moving pixels ({res.mask_frames} frames): precision "
                      f"{fmt(m.precision, 3)}, recall {fmt(m.recall, 3)}, IoU {fmt(m.iou_outlier, 3)}"]
    click.echo("\n".join(lines))
    if json_file is not None:
        d = {"groundtruth": str(res.gt_file), "estimate": str(est), "rpe": r.to_dict(per_pair=per_pair),
             "ate": a.to_dict(per_frame=per_pair), "masks": m.to_dict() if m is not None else None}
        if m is not None:
            d["mask_frames"] = res.mask_frames
        write_text(json_file, json.dumps(d, indent=1) + "\n")
    if plot_file is not None:
        _eval_plot(res, plot_file, delta, delta_unit)


def _eval_plot(res, plot_file, delta, delta_unit):
    from jaxvo import viz

    gs, gP = res.gt
    es, _ = res.est
    a, r = res.ate, res.rpe
    t0 = es[0]
    keep = (gs >= es[0] - 0.1) & (gs <= es[-1] + 0.1)
    u = "s" if delta_unit == "s" else "frame"
    fig = viz.plot_eval(gP[keep, :3, 3], a.aligned[:, :3, 3], r.stamps_j - t0, r.trans / r.delta,
                        a.stamps - t0, a.errors, rpe_label=f"RPE trans [m/{u}] (delta {delta:g} {u})",
                        title=f"{Path(str(res.gt_file)).parent.name}")
    try:
        writing(plot_file, lambda p: viz.save_figure(fig, p))
    except ValueError as e:
        raise DatasetError(f"{plot_file}: cannot write figure ({one_line(e)})") from None
