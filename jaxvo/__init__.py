"""jaxvo: robust dense RGB-D visual odometry in JAX."""
from jaxvo.camera import Camera, camera_for_sequence
from jaxvo import geometry

__all__ = ["Camera", "camera_for_sequence", "geometry"]
__version__ = "0.1.0"
