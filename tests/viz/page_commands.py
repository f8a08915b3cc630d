"""Reading meshcat's static page back (a helper of the tests in this folder, not a test module):
each drawing command is a base64 msgpack blob in the page, decoded with umsgpack. The page holds
them as one list (calib_oed.viz.sessions.inline_commands), or as meshcat writes them, one
``fetch`` each."""

from __future__ import annotations

import base64
import re

import numpy as np
import umsgpack


def decode_commands(html: str) -> list[dict]:
    """The meshcat commands embedded in a static page, in page order."""
    from calib_oed.viz.sessions import COMMANDS_BEGIN, COMMANDS_END

    if COMMANDS_BEGIN in html:
        block = html.split(COMMANDS_BEGIN, 1)[1].split(COMMANDS_END, 1)[0]
        blobs = re.findall(r'^"([A-Za-z0-9+/=]+)",$', block, flags=re.MULTILINE)
    else:
        blobs = re.findall(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)', html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def by_path(commands: list[dict], kind: str) -> dict[str, dict]:
    """The commands of one type (``set_object``, ...) by their node path."""
    return {c["path"]: c for c in commands if c["type"] == kind}


def transform(command: dict) -> np.ndarray:
    """The 4x4 matrix of a set_transform command (meshcat sends it column-major)."""
    return np.array(command["matrix"], dtype=float).reshape(4, 4).T
