"""Image readers: PNG (imagecodecs, 16 bits kept), TIFF (tifffile), camera raw (rawpy), masks."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from skintopo.errors import AcquisitionError, SkinTopoError
from skintopo.formats import read_png


RAW_SUFFIXES = (".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw")


def read_image(path):
    """Read a PNG or TIFF image with its native bit depth.

    Returns
    -------
    ndarray
        ``(rows, columns)`` or ``(rows, columns, 3)`` (RGB order; an alpha channel is dropped),
        in the file's own dtype (uint8, uint16 or float).

    Raises
    ------
    SkinTopoError
        Naming the file, when it is missing, of an unsupported type or unreadable.
    """
    path = Path(path)
    if not path.is_file():
        raise SkinTopoError(f"{path}: image file not found")
    suffix = path.suffix.lower()
    if suffix == ".png":
        image = read_png(path)
        if image.ndim == 3:
            image = image[..., :3] if image.shape[2] >= 3 else image[..., 0]  # alpha dropped
    elif suffix in (".tif", ".tiff"):
        import tifffile

        try:
            image = tifffile.imread(path)
        except Exception as exc:  # tifffile raises many types for damaged files
            raise SkinTopoError(f"{path}: not a readable TIFF image ({exc})") from None
        if image.ndim == 3 and image.shape[0] in (3, 4) and image.shape[2] not in (3, 4):
            image = np.moveaxis(image, 0, -1)  # planar RGB
        if image.ndim == 3:
            image = image[..., :3]
    elif suffix in RAW_SUFFIXES:
        image = read_raw(path)
    else:
        raise SkinTopoError(f"{path}: unsupported image type {suffix!r} (use PNG, TIFF or a camera raw file)")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise SkinTopoError(f"{path}: expected a grey or RGB image, got an array of shape {image.shape}")
    if not (np.issubdtype(image.dtype, np.unsignedinteger) or np.issubdtype(image.dtype, np.floating)):
        raise SkinTopoError(f"{path}: unsupported pixel type {image.dtype}")
    return np.ascontiguousarray(image)


def read_raw(path):
    """Camera raw via rawpy (LibRaw): demosaiced, linear (gamma 1), no auto-brightness, no
    white balance, the camera's native colour channels, 16 bits."""
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            return raw.postprocess(
                gamma=(1, 1), no_auto_bright=True, output_bps=16, use_camera_wb=False, use_auto_wb=False,
                user_wb=[1.0, 1.0, 1.0, 1.0], output_color=rawpy.ColorSpace.raw,
            )
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise SkinTopoError(f"{path}: not a readable camera raw file ({exc.__class__.__name__}: {exc})") from None


BASELINE_BYTES = 0.3 * 2**30  # Python, NumPy, SciPy and scikit-image loaded, before any image


def available_memory():
    """Bytes of memory this process can still take: MemAvailable of /proc/meminfo (Linux),
    elsewhere the machine's physical memory."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(source, shape, images, bytes_per_pixel):
    """Refuse a field that does not fit: ``images`` float32 images of ``shape`` plus the
    ``bytes_per_pixel`` that processing them needs beyond the images (the caller's figure)
    and the interpreter's baseline, against :func:`available_memory`. Raises
    :class:`AcquisitionError` naming the size needed and the size available."""
    rows, columns = shape
    need = rows * columns * (4 * images + bytes_per_pixel) + BASELINE_BYTES
    have = available_memory()
    if need > have:
        raise AcquisitionError(source, [f"a field of {columns} x {rows} pixels with {images:g} images needs about {need / 2**30:.1f} GiB "
                                        f"of memory to process; {have / 2**30:.1f} GiB are available (crop the images, or use a "
                                        "machine with more memory)"])


class ImageCache:
    """Reads each file once, checking that all images share one shape and one pixel type.

    ``memory``: (source, images, bytes per pixel): once the first image gives the field's
    size, :func:`check_memory` refuses a field that will not fit, before the other images are
    read."""

    def __init__(self, problems, memory=None):
        self.problems = problems
        self.images = {}
        self.reference = None  # (file, shape, dtype)
        self.memory = memory
        self.decoded = {}  # read ahead by prefetch, not yet checked: path -> image or SkinTopoError

    def prefetch(self, paths):
        """Read ``paths`` ahead, on two threads (the decoders release the GIL: 17 PNGs of
        1000 x 1000 in 0.17 s instead of 0.3), for :meth:`get` to check in its own order (the
        same problems, in the same order). The first is read and checked alone first, so that
        a field too large for memory is refused before the others are read."""
        paths = [p for p in dict.fromkeys(paths) if p not in self.images]
        if not paths:
            return
        self.get(paths[0])

        def read(path):
            try:
                return read_image(path)
            except SkinTopoError as exc:
                return exc

        with ThreadPoolExecutor(max_workers=2) as pool:
            self.decoded.update(zip(paths[1:], pool.map(read, paths[1:])))

    def get(self, path):
        if path in self.images:
            return self.images[path]
        try:
            image = self.decoded.pop(path) if path in self.decoded else read_image(path)
            if isinstance(image, SkinTopoError):
                raise image
        except SkinTopoError as exc:
            self.problems.append(str(exc))
            image = None
        if image is not None:
            if self.reference is None:
                self.reference = (path.name, image.shape[:2], image.dtype)
                if self.memory is not None:
                    source, images, bytes_per_pixel = self.memory
                    check_memory(source, image.shape[:2], images, bytes_per_pixel)
            else:
                ref_name, ref_shape, ref_dtype = self.reference
                if image.shape[:2] != ref_shape:
                    self.problems.append(
                        f"{path}: image size {image.shape[1]}x{image.shape[0]} differs from "
                        f"{ref_name} ({ref_shape[1]}x{ref_shape[0]})"
                    )
                    image = None
                elif image.dtype != ref_dtype:
                    self.problems.append(
                        f"{path}: pixel type {image.dtype} differs from {ref_name} ({ref_dtype}); "
                        "all images of an acquisition must share one bit depth"
                    )
                    image = None
        self.images[path] = image
        return image


def read_mask(path, shape, problems):
    try:
        mask = read_image(path)
    except SkinTopoError as exc:
        problems.append(str(exc))
        return None
    mask = mask.any(axis=2) if mask.ndim == 3 else mask > 0
    if shape is not None and mask.shape != shape:
        problems.append(f"{path}: mask size {mask.shape[1]}x{mask.shape[0]} differs from the images ({shape[1]}x{shape[0]})")
        return None
    return mask
