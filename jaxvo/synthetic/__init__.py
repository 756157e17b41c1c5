"""Synthetic dynamic RGB-D data with exact ground truth.

* :mod:`jaxvo.synthetic.scene`: textured primitives and the default room (:func:`make_room`).
* :mod:`jaxvo.synthetic.render`: exact NumPy ray casting (:func:`render`) and Kinect-like
  sensor effects (:class:`SensorModel`).
* :mod:`jaxvo.synthetic.motions`: Table II camera / person trajectories, :func:`make_sequence`.
* :mod:`jaxvo.synthetic.writer`: :func:`generate` a sequence into a TUM-layout folder (+ masks/).
* :mod:`jaxvo.synthetic.augment`: :func:`augment` a real static TUM sequence with moving occluders.

Conventions: poses are ``T_world_cam`` (4, 4) float64, camera-to-world; camera
frame x right, y down, z forward; depth in metres along z, 0 = invalid.
"""
from jaxvo.synthetic.scene import (Box, Cylinder, Rect, Scene, SceneObject, Texture, make_object,
                                   make_person, make_room, make_texture)
from jaxvo.synthetic.render import RenderResult, SensorModel, apply_sensor, render
from jaxvo.synthetic.motions import (SEQUENCES, FixedPose, Handheld, PanTilt, SyntheticSequence, Walk,
                                     make_sequence)
from jaxvo.synthetic.writer import generate, write_sequence
from jaxvo.synthetic.augment import augment

__all__ = [
    "Box", "Cylinder", "Rect", "Scene", "SceneObject", "Texture", "make_object", "make_person",
    "make_room", "make_texture", "RenderResult", "SensorModel", "apply_sensor", "render",
    "SEQUENCES", "FixedPose", "Handheld", "PanTilt", "SyntheticSequence", "Walk", "make_sequence",
    "generate", "write_sequence", "augment",
]
