"""Reading meshcat's static page back (a helper of the tests in this folder, not a test module):
each drawing command is a base64 msgpack blob in the page, decoded with umsgpack."""

from __future__ import annotations

import base64
import re

import numpy as np
import umsgpack


def decode_commands(html: str) -> list[dict]:
    """The meshcat commands embedded in a static page, in page order."""
    blobs = re.findall(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)', html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def by_path(commands: list[dict], kind: str) -> dict[str, dict]:
    """The commands of one type (``set_object``, ...) by their node path."""
    return {c["path"]: c for c in commands if c["type"] == kind}


def transform(command: dict) -> np.ndarray:
    """The 4x4 matrix of a set_transform command (meshcat sends it column-major)."""
    return np.array(command["matrix"], dtype=float).reshape(4, 4).T
