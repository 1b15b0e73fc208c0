"""Light directions: validation of unit vectors in the camera frame (x right, y up, z toward the camera)."""

from __future__ import annotations

import numpy as np

UNIT_TOLERANCE = 1e-3


def check_light_directions(lights, names=None):
    """List what is wrong with a set of light directions (an empty list if nothing).

    Each direction must be a finite, non-zero unit vector (norm within 1e-3 of 1) pointing
    toward the camera side (z > 0), and the set must hold at least three directions that are
    not coplanar (smallest / largest singular value of the m x 3 matrix above 1e-3): otherwise
    the Lambertian system n = (S^T S)^-1 S^T I has no unique solution.

    Parameters
    ----------
    lights : array_like, shape (m, 3)
    names : sequence of str, optional
        A label for each light, used in the messages.
    """
    lights = np.asarray(lights, dtype=np.float64)
    if lights.ndim != 2 or lights.shape[1] != 3:
        return [f"light directions must be an m x 3 array, got shape {lights.shape}"]
    names = names or [f"light {i}" for i in range(len(lights))]
    problems = []
    norms = np.linalg.norm(lights, axis=1)
    for name, light, norm in zip(names, lights, norms):
        if not np.all(np.isfinite(light)):
            problems.append(f"{name}: light direction {light.tolist()} is not finite")
        elif norm == 0:
            problems.append(f"{name}: light direction is the zero vector")
        elif abs(norm - 1) > UNIT_TOLERANCE:
            problems.append(f"{name}: light direction {light.tolist()} is not a unit vector (norm {norm:.4f})")
        elif light[2] <= 0:
            problems.append(f"{name}: light direction {light.tolist()} points away from the camera (z <= 0)")
    if len(lights) < 3:
        problems.append(f"only {len(lights)} light(s); photometric stereo needs at least 3")
    elif not problems:
        singular = np.linalg.svd(lights, compute_uv=False)
        if singular[-1] / singular[0] < 1e-3:
            problems.append("the light directions are coplanar: the surface normal cannot be solved for")
    return problems
