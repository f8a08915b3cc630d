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
        return vis.static_html(), info
    finally:
        _shutdown(vis)


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
