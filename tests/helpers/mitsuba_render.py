"""Independent renders for the physics tests: Mitsuba 3 (``scalar_rgb``, path tracer) on a
height-field mesh, orthographic camera, directional lights. Not part of the package: it is
the second renderer that keeps the physics method from being tested only against its own
forward model (:mod:`skintopo.synth.render`).

Red, green and blue are the three channels of one RGB render per light (the BSDF's
reflectance holds the band albedos). Radiance is multiplied by pi so that a Lambertian
surface under unit irradiance reads rho n . l, the convention of the acquisition format.
Subsurface scattering, when asked, is an exponential kernel exp(-r / d) per band applied to
the path-traced image (a kernel family different from the simulator's Gaussian).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import scipy.signal

PAD_PX = 4


def _write_ply(path, z, pixel):
    rows, columns = z.shape
    y, x = np.mgrid[0:rows, 0:columns]
    vertices = np.stack([(x - (columns - 1) / 2) * pixel, ((rows - 1) / 2 - y) * pixel, z], -1).reshape(-1, 3).astype("<f4")
    index = np.arange(rows * columns).reshape(rows, columns)
    a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    # counter-clockwise seen from +z (rows go down = -y)
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    face_records = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
    face_records["n"], face_records["i"] = 3, faces
    Path(path).write_bytes(header.encode() + vertices.tobytes() + face_records.tobytes())


def render(z_um, pixel_um, lights, albedo, *, coat_roughness=None, spp=64, max_depth=8, seed=0, face_normals=True, coat_colour=None):
    """Images (3 bands, m, rows, columns) of the height field ``z_um`` (micrometres).

    ``albedo``: (red, green, blue) diffuse reflectance; ``coat_roughness``: None for a
    purely diffuse surface, else a rough dielectric coat (Mitsuba ``roughplastic``, Beckmann
    alpha, index 1.38) over the diffuse base; ``coat_colour``: the coat's (red, green, blue)
    ``specular_reflectance``, a factor on its surface reflection alone (default 1: Mitsuba's;
    0: the coat's diffuse base alone, what crossed polarisers see). ``face_normals=False``:
    smooth vertex normals.
    """
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    rows, columns = z_um.shape
    scale = 1e-3  # scene in millimetres
    padded = np.pad(z_um, PAD_PX, mode="edge") * scale
    with tempfile.TemporaryDirectory() as folder:
        mesh_path = Path(folder) / "skin.ply"
        _write_ply(mesh_path, padded, pixel_um * scale)
        if coat_roughness is None:
            bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(albedo)}}
        else:
            bsdf = {"type": "roughplastic", "distribution": "beckmann", "alpha": coat_roughness, "int_ior": 1.38,
                    "diffuse_reflectance": {"type": "rgb", "value": list(albedo)}}
            if coat_colour is not None:
                bsdf["specular_reflectance"] = {"type": "rgb", "value": list(coat_colour)}
        half_w, half_h = columns * pixel_um * scale / 2, rows * pixel_um * scale / 2
        top = float(padded.max()) + 1.0
        images = []
        for light in np.asarray(lights, dtype=float):
            scene = mi.load_dict({
                "type": "scene",
                "integrator": {"type": "path", "max_depth": max_depth},
                "sensor": {
                    "type": "orthographic",
                    "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, top], target=[0, 0, 0], up=[0, 1, 0])
                    @ mi.ScalarTransform4f().scale([half_w, half_h, 1]),
                    "film": {"type": "hdrfilm", "width": columns, "height": rows, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                    "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
                },
                "skin": {"type": "ply", "filename": str(mesh_path), "bsdf": bsdf, "face_normals": face_normals},
                "light": {"type": "directional", "direction": (-light).tolist(), "irradiance": {"type": "rgb", "value": [1, 1, 1]}},
            })
            images.append(np.array(mi.render(scene), dtype=float) * np.pi)
    stack = np.stack(images)  # (m, rows, columns, 3)
    return np.moveaxis(stack, -1, 0)


def exponential_scattering(image, pixel_um, weight, length_um):
    """(1 - w) I + w (k * I), k(r) proportional to exp(-r / d), normalised, reflecting edges."""
    radius = int(np.ceil(6 * length_um / pixel_um))
    y, x = np.mgrid[-radius:radius + 1, -radius:radius + 1] * pixel_um
    kernel = np.exp(-np.hypot(x, y) / length_um)
    kernel /= kernel.sum()
    padded = np.pad(image, [(0, 0)] * (image.ndim - 2) + [(radius, radius), (radius, radius)], mode="symmetric")
    blurred = scipy.signal.fftconvolve(padded, kernel.reshape((1,) * (image.ndim - 2) + kernel.shape), mode="valid")
    return (1 - weight) * image + weight * blurred


def render_skin_edge(lights, albedo, *, coat_roughness=None, scattering=None, shape=(128, 256), pixel_um=20.0, spp=32, seed=2,
                     mask_reflectance=0.03):
    """A calibration capture for ``skintopo calibrate skin`` (red, green, blue images): a black
    mask (``mask_reflectance``) with a straight edge tilted by 2 degrees over a flat patch of the
    material (Mitsuba, every light at once), ``scattering`` ((weight, length um) per band, as
    :func:`exponential_scattering`) applied to the light the skin emits beside the mask; no
    light enters the skin under it."""
    flat = render(np.zeros(shape), pixel_um, lights, albedo, coat_roughness=coat_roughness, spp=spp, seed=seed).mean(axis=1)
    rows, columns = np.indices(shape, dtype=float)
    edge = 0.3 * shape[1] + np.tan(np.radians(2.0)) * (rows + 0.5)
    uncovered = np.clip(columns + 1.0 - edge, 0.0, 1.0)  # the share of each pixel beside the mask
    images = []
    for c in range(3):
        emitted = flat[c] * uncovered
        if scattering is not None:
            emitted = exponential_scattering(emitted, pixel_um, *scattering[c])
        images.append(uncovered * emitted + (1 - uncovered) * flat[c] * mask_reflectance / albedo[c])
    return np.stack(images)


def render_device(z_um, pixel_um, device, albedo, *, spp=32, max_depth=2, seed=0):
    """Images (3 bands, m, rows, columns) of the height field ``z_um`` (on a grid of
    ``pixel_um``, centred on the optical axis, h = 0 at the working distance) seen through
    ``device`` (:mod:`skintopo.device`): Mitsuba's ``perspective`` sensor with the device's
    field of view, one ``point`` emitter per LED (isotropic: the device's LEDs must have
    mu = 0), a diffuse BSDF with smooth vertex normals. ``max_depth=2``: direct light only."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    camera = device.camera
    rows, columns = camera.size_px
    fov = float(np.degrees(2 * np.arctan(columns / (2 * camera.focal_length_px))))
    z_mm = z_um / 1000.0 - device.working_distance_mm
    with tempfile.TemporaryDirectory() as folder:
        mesh_path = Path(folder) / "skin.ply"
        _write_ply(mesh_path, z_mm, pixel_um / 1000.0)
        images = []
        for led in device.leds:
            scene = mi.load_dict({
                "type": "scene",
                "integrator": {"type": "path", "max_depth": max_depth},
                "sensor": {
                    "type": "perspective", "fov": fov, "fov_axis": "x",
                    "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[0, 0, -1], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": columns, "height": rows, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                    "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
                },
                "skin": {"type": "ply", "filename": str(mesh_path), "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(albedo)}},
                         "face_normals": False},
                "light": {"type": "point", "position": list(led.position_mm), "intensity": {"type": "rgb", "value": [1, 1, 1]}},
            })
            images.append(np.array(mi.render(scene), dtype=float) * np.pi)
    return np.moveaxis(np.stack(images), -1, 0)
