"""The device description: files and their checks, the camera and LED models against closed forms."""

import json
import warnings

import numpy as np
import pytest

from skintopo.device import Camera, DeviceError, Led, paper_device, parse_device, read_device


def _device_dict(**changes):
    data = paper_device(size_px=64).describe()
    data.update(changes)
    return data


def test_device_file_round_trip(tmp_path):
    device = paper_device(size_px=64)
    path = tmp_path / "device.json"
    path.write_text(json.dumps(device.describe()))
    again = read_device(path)
    assert again.leds == device.leds and again.camera.focal_length_px == pytest.approx(device.camera.focal_length_px)
    assert again.pixel_um == pytest.approx(65000 / 64)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["camera"].update(focal_length_mm=0), "focal_length_mm must be a positive number"),
    (lambda d: d["camera"].update(focal_length_mm=-17), "focal_length_mm must be a positive number"),
    (lambda d: d["leds"][1].update(position_mm=[0, 60, -170]), "LED 'north' at z = -170 mm is behind the skin"),
    (lambda d: d["leds"][0].update(direction=[0, 0, 1]), "points away from the skin"),
    (lambda d: d["leds"][0].update(mu=-1), "mu must be a number >= 0"),
    (lambda d: d["leds"][2].update(intensity={"red": 0}), "intensity of red must be a positive number"),
    (lambda d: d.update(leds=d["leds"][:2]), "only 2 light(s)"),
    (lambda d: d["leds"][0].update(position_mm="far"), "'position_mm' must be [x, y, z] in millimetres"),
    (lambda d: d.update(colour="blue"), "unknown field 'colour'"),
])
def test_bad_device_files_get_clear_messages(tmp_path, change, message):
    data = _device_dict()
    change(data)
    path = tmp_path / "device.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DeviceError) as caught:
        read_device(path)
    assert message in str(caught.value) and "device.json" in str(caught.value)


@pytest.mark.parametrize("working, height", [(0.15, -0.1495), (150.0, -0.07)])
def test_positions_in_metres_are_warned_about(working, height):
    """Everything in metres (LEDs 0.5 um above the skin), or the LEDs alone (all at the camera)."""
    data = _device_dict(working_distance_mm=working)
    data["leds"] = [{"name": f"led{i}", "position_mm": [0.06 * np.cos(a), 0.06 * np.sin(a), height]}
                    for i, a in enumerate(np.radians([0, 90, 180, 270]))]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            parse_device(data, "metres.json")
            messages = [str(w.message) for w in caught]
        except DeviceError as error:  # LEDs at the camera also leave no usable light geometry
            messages = [str(error)]
    assert any("given in metres" in m and "metres.json" in m for m in messages), messages
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parse_device(_device_dict(), "millimetres.json")
    assert not caught


def test_camera_projection_inverts_its_rays_with_distortion():
    camera = Camera(12.0, 5.0, (40, 60), (31.2, 18.7), (-0.08, 0.02))
    columns, rows = np.meshgrid(np.linspace(0, 59, 7), np.linspace(0, 39, 5))
    a, b = camera.rays(columns, rows)
    depth = 97.0
    u, v = camera.project(np.stack([depth * a, depth * b, np.full(a.shape, -depth)]))
    assert np.allclose(u, columns, atol=1e-6) and np.allclose(v, rows, atol=1e-6)


def test_led_light_vector_is_inverse_square_with_its_angular_fall_off():
    # Closed forms: an isotropic source straight above gives Phi / r^2 along the axis; a
    # Lambertian emitter (mu = 1) seen 30 degrees off its axis gives cos(30) Phi / r^2.
    above = Led("a", (0.0, 0.0, -50.0), (0.0, 0.0, -1.0), mu=0.0, intensity={"red": 2.0})
    s = above.light_vectors(np.array([[0.0], [0.0], [-150.0]]), "red")[:, 0]
    assert np.allclose(s, [0, 0, 2.0 / 100.0**2])
    tilted = Led("b", (0.0, 0.0, 0.0), (0.0, 0.0, -1.0), mu=1.0)
    point = 80.0 * np.array([np.sin(np.radians(30)), 0.0, -np.cos(np.radians(30))])
    s = tilted.light_vectors(point[:, None])[:, 0]
    assert np.linalg.norm(s) == pytest.approx(np.cos(np.radians(30)) / 80.0**2)
    assert np.allclose(s / np.linalg.norm(s), -point / 80.0)
