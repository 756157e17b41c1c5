"""Where the keyframe window loses frames on a synthetic crowd seed: the held stretches of
``TrackConfig()`` and of variants (``recover`` off, the single reference), each variant in its
own process with one CPU thread, as ``experiments/drift.py`` runs them.

Example::

    python -m experiments.diagnostics.window_failures --seed 11 --frames 900
"""
from __future__ import annotations

import argparse
import json
import multiprocessing

import numpy as np

VARIANTS = {"window": {}, "no-recover": {"recover": False}, "single": {"window": 1}}


def run(job):
    seed, frames, size, name = job
    from experiments import drift
    drift._single_thread()
    import jax
    from jaxvo import geometry
    from jaxvo.camera import DEFAULT, camera_for_size
    from jaxvo.config import TrackConfig
    from jaxvo.frame import make_frame
    from jaxvo.synthetic import SensorModel, make_sequence
    from jaxvo.tracking.odometry import Odometry
    w, h = map(int, size.split("x"))
    camera = camera_for_size(DEFAULT, w, h)
    seq = make_sequence("crowd", frames=frames, seed=seed, camera=camera)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD21F7]))
    odo = Odometry(camera, key=jax.random.PRNGKey(seed), policy=TrackConfig(**VARIANTS[name]))
    lines = []
    for k in range(frames):
        r = seq.render(k, sensor=SensorModel(), rng=rng)
        step = odo.add(make_frame(r.rgb, r.depth))
        if k and not step.valid:
            err = np.linalg.norm((geometry.inverse(seq.poses[k]) @ seq.poses[odo.reference]
                                  @ geometry.inverse(odo._chain_pose(odo.reference)) @ step.T_world_cur)[:3, 3])
            lines.append(f"{name} frame {k}: held, reference {odo.reference}, window {odo._window}, "
                         f"moving {r.moving_mask.mean():.2f}, ratio {odo.inlier_ratio[-1]:.2f}, "
                         f"pose vs truth through the reference {err:.3f} m")
    stats = drift.drift_stats(seq.timestamps, seq.poses, np.stack(odo.poses))
    lines.append(f"{name}: " + json.dumps({k: round(v, 4) for k, v in stats.items()}))
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--frames", type=int, default=900)
    ap.add_argument("--size", default="320x240")
    args = ap.parse_args(argv)
    jobs = [(args.seed, args.frames, args.size, name) for name in VARIANTS]
    with multiprocessing.get_context("spawn").Pool(len(jobs)) as pool:
        for lines in pool.map(run, jobs):
            print("\n".join(lines), flush=True)


if __name__ == "__main__":
    main()
