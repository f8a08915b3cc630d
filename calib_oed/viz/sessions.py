r"""Showing the meshcat view: a live meshcat server, or one static HTML page.

:func:`open_viewer` starts a meshcat server (or connects to one) and draws
the view (:func:`calib_oed.viz.viewer.build_view`) into it; close the
:class:`LiveView` to stop the server. :func:`write_static_html` draws the
view in a server that runs for the call only and writes meshcat's
self-contained static page, which opens offline.

meshcat (which imports IPython and zmq) is imported only when a viewer starts.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from calib_oed.io.atomic import atomic_write_text
from calib_oed.viz.viewer import ViewInfo, build_view, check_design

if TYPE_CHECKING:
    import meshcat

    from calib_oed.calibration.workflow import Setup


class StaticView(NamedTuple):
    """What :func:`write_static_html` wrote: the file and what it shows."""

    path: Path
    info: ViewInfo


class LiveView:
    """A meshcat server showing a scene (:func:`open_viewer`); close it when done.

    Attributes:
        visualizer: The ``meshcat.Visualizer``.
        url: The page to open in a browser.
        info: What was drawn.
    """

    def __init__(self, visualizer: meshcat.Visualizer, info: ViewInfo):
        self.visualizer = visualizer
        self.url: str = visualizer.url()
        self.info = info

    def close(self) -> None:
        """Stop the meshcat server this view started (if it started one)."""
        _shutdown(self.visualizer)

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _start_visualizer(zmq_url: str | None = None):
    """A ``meshcat.Visualizer``; without ``zmq_url`` it starts a server subprocess."""
    try:
        with warnings.catch_warnings():  # meshcat 0.3 imports zmq.eventloop.ioloop (deprecated)
            warnings.simplefilter("ignore", DeprecationWarning)
            import meshcat
    except ImportError as exc:  # a dependency: a broken installation
        raise ImportError(f"the viewer needs meshcat (pip install 'meshcat>=0.3'): {exc}") from exc
    with contextlib.redirect_stdout(io.StringIO()):  # it prints its URL
        return meshcat.Visualizer(zmq_url=zmq_url)


def _shutdown(vis) -> None:
    """Close the visualizer's zmq socket and stop the server subprocess it started."""
    window = vis.window
    socket = getattr(window, "zmq_socket", None)
    if socket is not None and not socket.closed:
        socket.close(linger=0)
    proc = getattr(window, "server_proc", None)
    if proc is not None:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        for pipe in (proc.stdout, proc.stderr):
            if pipe is not None:
                pipe.close()


def static_html(s: Setup, q_design: np.ndarray | None = None, **kw: Any) -> tuple[str, ViewInfo]:
    """The view as meshcat's self-contained static page (text), and what it shows.

    A meshcat server subprocess runs for the duration of the call only (it is
    stopped on errors too). Keywords: those of :func:`~calib_oed.viz.viewer.build_view`.
    """
    check_design(s, q_design)  # before the server starts
    vis = _start_visualizer()
    try:
        info = build_view(vis, s, q_design, **kw)
        return inline_commands(vis.static_html()), info
    finally:
        _shutdown(vis)


#: One drawing command in meshcat's static page: a ``fetch`` of a base64 ``data:`` URL.
_FETCH = re.compile(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]*)"\)\s*'
                    r'\.then\(res => res\.arrayBuffer\(\)\)\s*'
                    r'\.then\(buffer => viewer\.handle_command_bytearray\(new Uint8Array\(buffer\)\)\);\s*')

#: Where :func:`inline_commands` puts the commands (``COMMANDS_BEGIN`` ... ``COMMANDS_END``).
COMMANDS_BEGIN = "// calib_oed: drawing commands, in order"
COMMANDS_END = "// calib_oed: end of drawing commands"

_REPLAY = """(() => {{  {begin}
  const commands = [
{blobs}
  ];  {end}
  for (const text of commands) {{
    const raw = atob(text);
    const bytes = new Uint8Array(raw.length);
    for (let i = 0; i < raw.length; i++) bytes[i] = raw.charCodeAt(i);
    viewer.handle_command_bytearray(bytes);
  }}
}})();
"""


def inline_commands(html: str) -> str:
    """meshcat's static page with its drawing commands replayed in one script, in order.

    meshcat writes one ``fetch`` of a ``data:`` URL per command (5743 for a
    60-pose UR10 design with capsules). Each is a request of its own, resolved
    in no guaranteed order, and the viewer redraws between them: in headless
    Chromium with software WebGL such a page did not finish loading within
    300 s (docs/benchmarks.md, issue 34). Here the same base64 blobs are
    decoded with ``atob`` and handed to ``viewer.handle_command_bytearray`` one
    after the other in a single script, so the scene is complete before the
    first frame is drawn. The page stays self-contained; a page without such
    commands is returned as it is.
    """
    blobs: list[str] = []

    def take(match: re.Match) -> str:
        blobs.append(match.group(1))
        return "\0calib_oed_commands\0" if len(blobs) == 1 else ""

    replaced = _FETCH.sub(take, html)
    if not blobs:
        return html
    script = _REPLAY.format(begin=COMMANDS_BEGIN, end=COMMANDS_END,
                            blobs="\n".join(f'"{b}",' for b in blobs))
    return replaced.replace("\0calib_oed_commands\0", script, 1)


def write_static_html(path: str | os.PathLike, s: Setup, q_design: np.ndarray | None = None,
                      **kw: Any) -> StaticView:
    """Write the view to one HTML file that opens offline (meshcat's static export), atomically.

    The page holds the viewer's JavaScript and every drawing command as inline
    ``data:`` URLs: it needs neither network nor server. Keywords: those of
    :func:`~calib_oed.viz.viewer.build_view`.

    Raises:
        ExportError: the file cannot be written (missing folder, ...).
        ShapeError, ViewerSettingError, ...: as :func:`~calib_oed.viz.viewer.build_view`.
    """
    html, info = static_html(s, q_design, **kw)
    return StaticView(atomic_write_text(path, html), info)


def open_viewer(s: Setup, q_design: np.ndarray | None = None, *, zmq_url: str | None = None,
                **kw: Any) -> LiveView:
    """Start a meshcat server (or connect to ``zmq_url``) and draw the view in it.

    Returns a :class:`LiveView`: open its ``url`` in a browser; close it (or use it
    in a ``with`` block) to stop the server. Keywords: those of :func:`~calib_oed.viz.viewer.build_view`.
    """
    check_design(s, q_design)  # before the server starts
    vis = _start_visualizer(zmq_url)
    try:
        info = build_view(vis, s, q_design, **kw)
    except BaseException:
        _shutdown(vis)
        raise
    return LiveView(vis, info)
