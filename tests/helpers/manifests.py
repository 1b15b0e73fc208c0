"""Editing an acquisition's manifest in place (tests that break one field at a time)."""

import json


def edit_manifest(folder, change):
    """Load ``folder``/acquisition.json, let ``change`` modify the dict, write it back."""
    path = folder / "acquisition.json"
    manifest = json.loads(path.read_text())
    change(manifest)
    path.write_text(json.dumps(manifest))
