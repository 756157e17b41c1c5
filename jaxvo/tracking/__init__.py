"""Frames in, poses out: Odometry / track, the keyframe policy, the static/dynamic segmentation, batches.

Modules: :mod:`~jaxvo.tracking.odometry` (:class:`Odometry`, :func:`track`: the reference choice,
held poses, chaining), :mod:`~jaxvo.tracking.static_map` (the segmentation's state and compiled
programs, :class:`StaticMap`), :mod:`~jaxvo.tracking.segmentation` (its maths),
:mod:`~jaxvo.tracking.batch` (several sequences' estimates as one batched call) and
:mod:`~jaxvo.tracking.hindsight` (moving masks of a tracked sequence, from frames before and after).
"""
