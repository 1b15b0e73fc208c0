"""The device: a perspective camera and near-field LEDs (``device.json``), in millimetres.

Every light in the distant-light model is a direction at infinity and the camera is
orthographic. A real skin camera is not: its LEDs sit a few centimetres to a decimetre from
the skin, so the direction to an LED changes by tens of degrees across the field and its
irradiance falls with distance and with the LED's own angular profile. This module describes
such a device and computes, for any 3-D point, what each LED delivers there.

Frame and units
    The camera frame of the whole project (x right, y up, z toward the camera), with its
    origin at the camera's centre of projection. The skin lies in front of the camera, at
    z ~ -``working_distance_mm``. Positions and distances are in millimetres here (a device
    is built in millimetres); heights leave the near-field solver in micrometres.

Camera (pinhole with optional radial distortion)
    A pixel (column u, row v; (0, 0) is the centre of the top-left pixel) sees the ray
    P = d (a, b, -1), with (a, b) = ((u - c_u), -(v - c_v)) pixel_pitch / f after removing
    the radial distortion x_d = x (1 + k1 r^2 + k2 r^4) (Brown's model, normalised
    coordinates), d > 0 the depth along the optical axis.

LEDs (Quéau, Durix, Wu, Cremers, Lauze & Durou 2018, "LED-based photometric stereo:
modeling, calibration and numerical solution", J. Math. Imaging Vis. 60, eq. 4)
    An LED at position L with principal direction a (unit, toward the skin), anisotropy mu
    and intensity Phi_band lights a point P with the light vector

        s(P) = Phi (cos theta)^mu (L - P) / |L - P|^3,    cos theta = a . (P - L) / |P - L|,

    so a Lambertian point of albedo rho and normal n shows I = rho n . s(P) (the distant-light
    model is the limit |L| -> infinity with |L|^2 folded into Phi). mu = 0 is an isotropic
    point source, mu = 1 a Lambertian emitter. Intensities are relative (a common factor goes
    into the albedo): only their ratios between LEDs and bands matter.

The device file::

    {"format": "skintopo-device", "version": 1,
     "working_distance_mm": 150,
     "camera": {"focal_length_mm": 17.08, "pixel_pitch_um": 7.4, "size_px": [1000, 1000],
                "principal_point_px": [499.5, 499.5], "radial_distortion": [0, 0]},
     "leds": [{"name": "east", "position_mm": [60, 0, -70], "direction": [...],
               "mu": 1.0, "intensity": {"red": 1, "green": 1, "blue": 1}}, ...]}

``direction`` is optional (default: toward the point of the optical axis at the working
distance), as are ``principal_point_px`` (default: the image centre), ``radial_distortion``
(none), ``mu`` (1) and ``intensity`` (1 in every band).
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skintopo.errors import SkinTopoError, header_problems
from skintopo.outputs import write_json_atomic
from skintopo.lights import check_light_directions

FORMAT_NAME = "skintopo-device"
FORMAT_VERSION = 1
DEVICE_NAME = "device.json"
_DEVICE_KEYS = {"format", "version", "working_distance_mm", "camera", "leds", "description"}
_CAMERA_KEYS = {"focal_length_mm", "pixel_pitch_um", "size_px", "principal_point_px", "radial_distortion"}
_LED_KEYS = {"name", "position_mm", "direction", "mu", "intensity"}
NEAR_SKIN_MM = 1.0  # LEDs closer than this to the skin, or all this close to the camera: metres given?


class DeviceError(SkinTopoError):
    """A device description that cannot be used; the message lists every problem."""

    def __init__(self, source, problems):
        self.source = str(source)
        self.problems = list(problems)
        super().__init__(f"{source}: " + "; ".join(self.problems))


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with optional radial distortion. Lengths in millimetres except the
    pixel pitch (micrometres) and image coordinates (pixels)."""

    focal_length_mm: float
    pixel_pitch_um: float
    size_px: tuple  # (rows, columns)
    principal_point_px: tuple | None = None  # (column, row); None: the image centre
    radial_distortion: tuple = (0.0, 0.0)  # (k1, k2), normalised coordinates

    def __post_init__(self):  # sequences as tuples: a camera is a value (hashable, e.g. a cache key)
        for name in ("size_px", "principal_point_px", "radial_distortion"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, tuple(value))

    @property
    def centre(self):
        """(c_u, c_v): the principal point in pixels (column, row)."""
        if self.principal_point_px is not None:
            return tuple(float(c) for c in self.principal_point_px)
        rows, columns = self.size_px
        return ((columns - 1) / 2, (rows - 1) / 2)

    @property
    def focal_length_px(self):
        """f / pixel pitch: the focal length in pixels."""
        return self.focal_length_mm * 1000.0 / self.pixel_pitch_um

    def footprint_um(self, depth_mm):
        """Side of one pixel on a plane facing the camera at ``depth_mm``: d pitch / f."""
        return depth_mm * self.pixel_pitch_um / self.focal_length_mm

    def _undistort(self, xd, yd):
        k1, k2 = self.radial_distortion
        if k1 == 0 and k2 == 0:
            return xd, yd
        x, y = xd.copy(), yd.copy()
        for _ in range(20):  # fixed point x = x_d / (1 + k1 r^2 + k2 r^4): converges for |k r^2| << 1
            r2 = x * x + y * y
            factor = 1 + k1 * r2 + k2 * r2 * r2
            x, y = xd / factor, yd / factor
        return x, y

    def binned(self, factor):
        """The same camera with ``factor`` x ``factor`` pixels summed into one (the image
        cropped to whole blocks): pixel (i, j) of the binned image is the block whose centre
        is at (factor i + (factor - 1) / 2, ...) of this one."""
        cu, cv = self.centre
        rows, columns = self.size_px
        return Camera(self.focal_length_mm, self.pixel_pitch_um * factor, (rows // factor, columns // factor),
                      ((cu - (factor - 1) / 2) / factor, (cv - (factor - 1) / 2) / factor), self.radial_distortion)

    def rays(self, columns=None, rows=None):
        """(a, b) per pixel: the pixel sees the points d (a, b, -1), d > 0.

        With no arguments, for every pixel of the image (arrays of ``size_px``); else for the
        given (sub-)pixel coordinates.
        """
        if columns is None:
            rows, columns = np.meshgrid(np.arange(self.size_px[0], dtype=float), np.arange(self.size_px[1], dtype=float), indexing="ij")
        cu, cv = self.centre
        scale = 1.0 / self.focal_length_px
        return self._undistort((np.asarray(columns, dtype=float) - cu) * scale, -(np.asarray(rows, dtype=float) - cv) * scale)

    def project(self, points):
        """Image coordinates (column, row) of camera-frame points (3, ...), in millimetres."""
        points = np.asarray(points, dtype=float)
        x, y = points[0] / -points[2], points[1] / -points[2]
        k1, k2 = self.radial_distortion
        r2 = x * x + y * y
        factor = 1 + k1 * r2 + k2 * r2 * r2
        cu, cv = self.centre
        return cu + x * factor * self.focal_length_px, cv - y * factor * self.focal_length_px


@dataclass(frozen=True)
class Led:
    """One LED: position (mm, camera frame), principal direction (unit, toward the skin),
    anisotropy mu and relative intensity per band."""

    name: str
    position_mm: tuple
    direction: tuple
    mu: float = 1.0
    intensity: dict = field(default_factory=lambda: {"red": 1.0, "green": 1.0, "blue": 1.0})

    def light_vectors(self, points, band=None):
        """s(P) = Phi (cos theta)^mu (L - P) / |L - P|^3 at camera-frame points in mm
        (Phi: the LED's intensity in ``band``; 1 when ``band`` is None).

        ``points`` has shape (3, ...): x, y and z first (each component contiguous, which is
        several times faster than (..., 3) for the per-pixel arithmetic); so has the result,
        in the points' floating type. Points behind the LED (cos theta <= 0) get no light.
        """
        points = np.asarray(points)
        dtype = points.dtype if points.dtype.kind == "f" else np.float64
        towards = [dtype.type(c) - p for c, p in zip(self.position_mm, points)]
        distance2 = towards[0] * towards[0] + towards[1] * towards[1] + towards[2] * towards[2]
        inverse = 1 / np.sqrt(distance2)
        a = self.direction
        cos_theta = -(towards[0] * a[0] + towards[1] * a[1] + towards[2] * a[2]) * inverse
        phi = 1.0 if band is None else self.intensity.get(band, 1.0)
        strength = np.maximum(cos_theta, 0) ** dtype.type(self.mu) * (inverse * inverse * inverse * dtype.type(phi))
        return np.stack([t * strength for t in towards])


@dataclass(frozen=True)
class Device:
    """A camera, its LEDs and the working distance (mm from the centre of projection to the
    skin plane, along the optical axis)."""

    camera: Camera
    leds: tuple
    working_distance_mm: float
    description: str = ""

    def led(self, name):
        """The LED called ``name``."""
        for led in self.leds:
            if led.name == name:
                return led
        raise SkinTopoError(f"the device has no LED named {name!r}; it has {[led.name for led in self.leds]}")

    @property
    def pixel_um(self):
        """The pixel footprint on the skin plane at the working distance, in micrometres."""
        return self.camera.footprint_um(self.working_distance_mm)

    def field_point(self):
        """The point of the optical axis at the working distance: (0, 0, -D)."""
        return np.array([0.0, 0.0, -self.working_distance_mm])

    def central_directions(self):
        """Unit directions from the field centre to each LED, (m, 3): the distant lights a
        distant-light solver would be given for this device."""
        towards = np.array([led.position_mm for led in self.leds], dtype=float) - self.field_point()
        return towards / np.linalg.norm(towards, axis=1, keepdims=True)

    def describe(self):
        """The device file's content (JSON-ready)."""
        cam = self.camera
        return {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "description": self.description,
            "working_distance_mm": self.working_distance_mm,
            "camera": {
                "focal_length_mm": cam.focal_length_mm,
                "pixel_pitch_um": cam.pixel_pitch_um,
                "size_px": list(cam.size_px),
                "principal_point_px": list(cam.centre),
                "radial_distortion": list(cam.radial_distortion),
            },
            "leds": [
                {"name": led.name, "position_mm": list(led.position_mm), "direction": list(led.direction), "mu": led.mu,
                 "intensity": dict(led.intensity)}
                for led in self.leds
            ],
        }


def aimed_at(position_mm, target_mm):
    """Unit direction from an LED at ``position_mm`` toward ``target_mm``."""
    direction = np.asarray(target_mm, dtype=float) - np.asarray(position_mm, dtype=float)
    return tuple(float(c) for c in direction / np.linalg.norm(direction))


def paper_device(*, size_px=1000, led_radius_mm=60.0, led_height_mm=80.0, mu=1.0):
    """A device like the paper's (Sohaib et al.): 4 LEDs at 90 degrees, a 1000 x 1000 camera
    (AVT Pike F100C: 7.4 um pixels) seeing about 65 x 65 mm at 150 mm (65 um per pixel).

    The LEDs sit on a ring of ``led_radius_mm`` at ``led_height_mm`` above the skin plane,
    aimed at the field centre. These distances are ours (the paper gives the field and the
    camera, not the LED geometry): with them the direction to an LED changes by about 30
    degrees across the field.
    """
    working = 150.0
    pitch = 7.4
    focal = working * pitch * 1000 / (65.0 * 1000)  # field 65 mm over 1000 pixels
    focal *= size_px / 1000  # same field at another pixel count
    camera = Camera(focal_length_mm=focal, pixel_pitch_um=pitch, size_px=(size_px, size_px))
    centre = (0.0, 0.0, -working)
    leds = []
    for name, angle in (("east", 0), ("north", 90), ("west", 180), ("south", 270)):
        position = (led_radius_mm * math.cos(math.radians(angle)), led_radius_mm * math.sin(math.radians(angle)), -working + led_height_mm)
        position = tuple(round(c, 9) + 0.0 for c in position)
        leds.append(Led(name, position, aimed_at(position, centre), mu))
    return Device(camera, tuple(leds), working, description="paper-like device (skintopo.device.paper_device)")


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _vector(value, length):
    return isinstance(value, (list, tuple)) and len(value) == length and all(_number(v) for v in value)


def check_device(device: Device):
    """(problems, warnings) of a device: lists of messages, empty when all is well.

    Problems: a focal length, pixel pitch or working distance that is not positive; an LED
    at or behind the skin plane (z <= -D) or aimed away from the skin; a negative mu; an intensity that is not positive;
    fewer than three LEDs, or LEDs whose directions from the field centre are coplanar.
    Warnings (units): an LED within ``NEAR_SKIN_MM`` of the skin plane, or every LED within
    it of the camera, which is what positions (or a working distance) in metres look like.
    """
    problems, warns = [], []
    cam = device.camera
    if not (_number(cam.focal_length_mm) and cam.focal_length_mm > 0):
        problems.append(f"camera focal_length_mm must be a positive number of millimetres, got {cam.focal_length_mm!r}")
    if not (_number(cam.pixel_pitch_um) and cam.pixel_pitch_um > 0):
        problems.append(f"camera pixel_pitch_um must be a positive number of micrometres, got {cam.pixel_pitch_um!r}")
    working = device.working_distance_mm
    if not (_number(working) and working > 0):
        problems.append(f"working_distance_mm must be a positive number of millimetres, got {working!r}")
    if problems:
        return problems, warns
    half_field_mm = 0.5 * max(cam.size_px) * device.pixel_um / 1000
    for led in device.leds:
        position = np.asarray(led.position_mm, dtype=float)
        direction = np.asarray(led.direction, dtype=float)
        if position[2] <= -working:
            problems.append(f"LED {led.name!r} at z = {position[2]:g} mm is behind the skin (the skin plane is at z = {-working:g} mm): "
                            "LEDs sit between the camera and the skin")
        if abs(np.linalg.norm(direction) - 1) > 1e-3:
            problems.append(f"LED {led.name!r}: direction {direction.tolist()} is not a unit vector")
        elif direction[2] >= 0:
            problems.append(f"LED {led.name!r}: direction {direction.tolist()} points away from the skin (z >= 0)")
        if not (_number(led.mu) and led.mu >= 0):
            problems.append(f"LED {led.name!r}: mu must be a number >= 0, got {led.mu!r}")
        for band, value in led.intensity.items():
            if not (_number(value) and value > 0):
                problems.append(f"LED {led.name!r}: intensity of {band} must be a positive number, got {value!r}")
        above_skin = position[2] + working
        if 0 < above_skin < NEAR_SKIN_MM:
            where = "inside" if np.hypot(position[0], position[1]) < half_field_mm else "beside"
            warns.append(f"LED {led.name!r} sits {above_skin * 1000:.0f} um above the skin, {where} the field: "
                         "were positions or the working distance given in metres? They are in millimetres")
    if device.leds and max(np.linalg.norm(led.position_mm) for led in device.leds) < NEAR_SKIN_MM < working:
        warns.append("every LED is within 1 mm of the camera's centre: were the positions given in metres? They are in millimetres")
    if not problems:
        names = [f"LED {led.name!r}" for led in device.leds]
        problems += check_light_directions(device.central_directions(), names)
    return problems, warns


def parse_device(data, source="device"):
    """A :class:`Device` from the device file's content (a dict), checked; every problem
    is reported at once (:class:`DeviceError`), and unit warnings are issued."""
    if not isinstance(data, dict):
        raise DeviceError(source, ["the device file must hold a JSON object"])
    problems = header_problems(data, _DEVICE_KEYS, FORMAT_NAME, FORMAT_VERSION)
    working = data.get("working_distance_mm")
    if not _number(working):
        problems.append(f"field 'working_distance_mm' must be a number of millimetres, got {working!r}")
    camera = data.get("camera")
    if not isinstance(camera, dict):
        problems.append("field 'camera' must be an object")
        camera = {}
    for key in sorted(set(camera) - _CAMERA_KEYS):
        problems.append(f"camera: unknown field {key!r}")
    for key in ("focal_length_mm", "pixel_pitch_um"):
        if not _number(camera.get(key)):
            problems.append(f"camera: field {key!r} must be a number, got {camera.get(key)!r}")
    size = camera.get("size_px")
    if not (_vector(size, 2) and all(float(s).is_integer() and s > 0 for s in size)):
        problems.append(f"camera: field 'size_px' must be [rows, columns], got {size!r}")
    if "principal_point_px" in camera and not _vector(camera["principal_point_px"], 2):
        problems.append(f"camera: field 'principal_point_px' must be [column, row], got {camera['principal_point_px']!r}")
    if "radial_distortion" in camera and not _vector(camera["radial_distortion"], 2):
        problems.append(f"camera: field 'radial_distortion' must be [k1, k2], got {camera['radial_distortion']!r}")
    entries = data.get("leds")
    if not isinstance(entries, list) or not entries:
        problems.append("field 'leds' must be a non-empty list")
        entries = []
    leds = []
    for i, entry in enumerate(entries):
        label = f"leds[{i}]"
        if not isinstance(entry, dict):
            problems.append(f"{label} must be an object")
            continue
        for key in sorted(set(entry) - _LED_KEYS):
            problems.append(f"{label}: unknown field {key!r}")
        name = entry.get("name", str(i))
        position = entry.get("position_mm")
        if not _vector(position, 3):
            problems.append(f"{label}: field 'position_mm' must be [x, y, z] in millimetres, got {position!r}")
            continue
        direction = entry.get("direction")
        if direction is None and _number(working):
            direction = aimed_at(position, (0.0, 0.0, -working))
        elif not _vector(direction, 3):
            problems.append(f"{label}: field 'direction' must be a unit vector [x, y, z], got {direction!r}")
            continue
        intensity = entry.get("intensity", {"red": 1.0, "green": 1.0, "blue": 1.0})
        if not isinstance(intensity, dict):
            problems.append(f"{label}: field 'intensity' must map bands to numbers, got {intensity!r}")
            continue
        leds.append(Led(str(name), tuple(float(c) for c in position), tuple(float(c) for c in direction), entry.get("mu", 1.0), dict(intensity)))
    if len({led.name for led in leds}) != len(leds):
        problems.append("LED names must be unique")
    if problems:
        raise DeviceError(source, problems)
    device = Device(
        Camera(float(camera["focal_length_mm"]), float(camera["pixel_pitch_um"]), tuple(int(s) for s in size),
               camera.get("principal_point_px"), tuple(camera.get("radial_distortion", (0.0, 0.0)))),
        tuple(leds), float(working), str(data.get("description", "")),
    )
    problems, warns = check_device(device)
    if problems:
        raise DeviceError(source, problems + warns)  # the unit warnings often explain the problems
    for message in warns:
        warnings.warn(f"{source}: {message}", UserWarning, stacklevel=2)
    return device


def read_device(path):
    """Read and check a device file (see the module notes for its format)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DeviceError(path, [f"not a readable JSON device file ({exc})"]) from None
    return parse_device(data, source=path)


def write_device(path, device: Device):
    """Write ``device`` as a device file (the output of ``skintopo calibrate leds``), whole or
    not at all (a temporary file renamed into place)."""
    write_json_atomic(path, device.describe())
