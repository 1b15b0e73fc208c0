"""skintopo: 3D skin topography by multispectral photometric stereo.

The measurement flows one way through one module per stage::

    acquisition -> normals -> height -> correction -> measurements -> report

Heights and lengths are in micrometres throughout the API. Light directions and
normals are unit vectors in the camera frame: x right, y up, z toward the camera.
Height is positive toward the camera.
"""

from skintopo.errors import AcquisitionError, SkinTopoError

__version__ = "0.1.0"

__all__ = ["AcquisitionError", "HeightMap", "SkinTopoError", "__version__"]


def __getattr__(name):
    # HeightMap on first use (PEP 562): ``import skintopo`` and ``skintopo --help`` need no NumPy
    if name == "HeightMap":
        from skintopo.heightmap import HeightMap

        return HeightMap
    raise AttributeError(f"module 'skintopo' has no attribute {name!r}")
