"""Writing results safely: an output folder appears complete or not at all, and never over
the inputs."""

from __future__ import annotations

import json
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from skintopo.errors import SkinTopoError
from skintopo.formats import atomic_write, current_umask, fsync_path, write_png


def check_output_folder(out, *, overwrite=False, inputs=()):
    """Refuse an output folder that would overwrite something, before any work is done.

    ``out`` may not exist, may be empty, or (with ``overwrite``) may hold an earlier result;
    it may never be, contain, or lie inside one of ``inputs``.
    """
    out = Path(out).resolve()
    for source in inputs:
        source = Path(source).resolve()
        if out == source or source.is_relative_to(out) or out.is_relative_to(source):
            raise SkinTopoError(f"{out}: the output folder overlaps the input {source}; choose another -o")
    if out.exists():
        if not out.is_dir():
            raise SkinTopoError(f"{out}: exists and is not a folder")
        if any(out.iterdir()) and not overwrite:
            raise SkinTopoError(f"{out}: folder is not empty; use --overwrite to replace it")


def check_output_file(out, *, overwrite=False, inputs=()):
    """Refuse an output file that would overwrite an input or something not asked for.

    ``out`` may never be one of ``inputs`` nor lie inside an input folder (with or without
    ``overwrite``); an existing file is replaced only with ``overwrite``; a folder never.
    """
    out = Path(out).resolve()
    for source in inputs:
        source = Path(source).resolve()
        if out == source or out.is_relative_to(source):
            raise SkinTopoError(f"{out}: the output would overwrite or lie inside the input {source}; choose another -o")
    if out.is_dir():
        raise SkinTopoError(f"{out}: is a folder; give a file name to write")
    if out.exists() and not overwrite:
        raise SkinTopoError(f"{out}: exists; use --overwrite to replace it")


@contextmanager
def staged_output_folder(out, *, overwrite=False, inputs=()):
    """Yield a temporary folder beside ``out``; on success its files are synced to the disk
    and it replaces ``out`` in one rename.

    If the body raises (or is interrupted), the temporary folder is removed and ``out`` is
    left as it was.
    """
    check_output_folder(out, overwrite=overwrite, inputs=inputs)
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    staging.chmod(0o777 & ~current_umask())
    try:
        yield staging
        for file in sorted(staging.rglob("*"), reverse=True):  # files, then their folders: durable before the rename
            fsync_path(file)
        fsync_path(staging)
        if out.exists():
            shutil.rmtree(out)
        staging.rename(out)
        fsync_path(out.parent)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def write_json(path, data):
    """Write ``data`` as indented JSON (NumPy scalars and arrays converted)."""
    Path(path).write_text(json.dumps(data, indent=2, default=_json_default, allow_nan=True) + "\n", encoding="utf-8")


def write_json_atomic(path, data):
    """Write JSON to a temporary file beside ``path`` and rename it into place."""
    atomic_write(path, lambda tmp: write_json(tmp, data))


def write_label_image(path, labels):
    """Write a label image (0 = background, i = object i) as an 8- or 16-bit PNG."""
    labels = np.asarray(labels)
    if labels.max(initial=0) > 65535:
        raise SkinTopoError(f"{path}: more than 65535 labels cannot be stored in a PNG")
    write_png(path, labels.astype(np.uint8 if labels.max(initial=0) <= 255 else np.uint16))
