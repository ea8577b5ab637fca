"""rigcal: calibrate the cameras of a drone's camera rig.

Public API::

    import rigcal
    rig = rigcal.load_rig("rigs/drone-stereo-back.yaml")
    T_nav_body = rigcal.T_nav_body_from_heading([100, 300, 10], 0.0)
    seen = rig.project([[103, 310, 12]], T_nav_body)      # per camera Projection
    depth = rig.stereo_depth(rig.stereo_pairs[0], [[103, 310, 12]], T_nav_body)
"""

from rigcal.core.camera import CameraModel
from rigcal.errors import CalibrationError, InputError, RigcalError, RigFileError
from rigcal.core.geometry import T_nav_body_from_axes, T_nav_body_from_heading, inv_T, make_T, transform
from rigcal.core.rig import Camera, Imu, Projection, Rig, StereoPair, dump_rig, load_rig, parse_rig, save_rig

__version__ = "0.1.0"

__all__ = [
    "CameraModel", "Camera", "Imu", "Projection", "Rig", "StereoPair",
    "RigcalError", "InputError", "RigFileError", "CalibrationError",
    "load_rig", "parse_rig", "save_rig", "dump_rig",
    "T_nav_body_from_heading", "T_nav_body_from_axes", "make_T", "inv_T", "transform",
    "__version__",
]
