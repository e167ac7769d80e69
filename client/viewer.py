"""``render_mode="human"``: the arena's top-down picture in a window, in real time.

A face built with ``render_mode="human"`` shows each new frame after ``reset`` and every
``step`` (Gymnasium's and PettingZoo's convention; ``render()`` then returns None), at
most ``render_fps`` frames per second of wall time so an episode plays at the speed it is
simulated. The window is a plain Tk window (``tkinter`` from the standard library and
Pillow's ``ImageTk``), so no extra package is needed.

Where there is no display (a server, CI, an SSH session without X forwarding) the face
refuses ``"human"`` when it is built, before any arena or server starts, and says what to
do instead; its metadata then lists ``"rgb_array"`` only, so checkers that try every
declared mode (Gymnasium's ``check_env``) do not ask for a window that cannot open.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, MissingDependencyError

HUMAN = "human"
RGB_ARRAY = "rgb_array"


def display_problem() -> tuple[type[Exception], str] | None:
    """Why a window cannot open here, as the error to raise and its reason (None if it can,
    as far as can be told without opening one)."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return InvalidOptionError, "there is no display ($DISPLAY and $WAYLAND_DISPLAY are not set)"
    try:
        import tkinter  # noqa: F401

        from PIL import ImageTk  # noqa: F401
    except ImportError as exc:
        return MissingDependencyError, f"tkinter or Pillow's ImageTk cannot be imported ({exc})"
    return None


def render_modes() -> list[str]:
    """The render modes a face offers on this machine: ``"human"`` only where a window can
    open, and ``"rgb_array"`` always."""
    return [HUMAN, RGB_ARRAY] if display_problem() is None else [RGB_ARRAY]


def check_render_mode(render_mode: str | None) -> None:
    """Refuse a render mode the faces do not have, or ``"human"`` where no window can open,
    naming what works instead."""
    if render_mode is None or render_mode == RGB_ARRAY:
        return
    if render_mode != HUMAN:
        raise InvalidOptionError(
            f"render_mode={render_mode!r} is not one of {[HUMAN, RGB_ARRAY]} or None"
        )
    problem = display_problem()
    if problem is not None:
        error, reason = problem
        raise error(
            f"render_mode='human' opens a window, but {reason}; use render_mode='rgb_array' "
            "and save the frames (e.g. gymnasium.wrappers.RecordVideo, or imageio), or run "
            "where there is a display (X forwarding: ssh -X; a virtual one: xvfb-run)"
        )


class Window:
    """A Tk window that shows RGB frames, opened on the first frame."""

    def __init__(self, title: str, fps: float) -> None:
        self.title, self.period = title, 1.0 / fps if fps > 0 else 0.0
        self._root: Any = None
        self._label: Any = None
        self._photo: Any = None
        self._last = 0.0

    def show(self, frame: np.ndarray) -> None:
        """Show ``frame`` (H × W × 3 uint8), waiting first so frames keep ``fps``."""
        import tkinter

        from PIL import Image, ImageTk

        if self._root is None:
            try:
                self._root = tkinter.Tk()
            except tkinter.TclError as exc:
                raise InvalidOptionError(
                    f"render_mode='human' could not open a window ({exc}); use "
                    "render_mode='rgb_array' where there is no display"
                ) from exc
            self._root.title(self.title)
            self._label = tkinter.Label(self._root)
            self._label.pack()
        wait = self._last + self.period - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        self._photo = ImageTk.PhotoImage(Image.fromarray(np.asarray(frame, dtype=np.uint8)))
        self._label.configure(image=self._photo)
        self._root.update()
        self._last = time.monotonic()

    @property
    def is_open(self) -> bool:
        return self._root is not None

    def close(self) -> None:
        """Close the window if it is open; safe to repeat."""
        root, self._root = self._root, None
        if root is not None:
            import tkinter

            with contextlib.suppress(tkinter.TclError):  # the user closed it already
                root.destroy()


class Renderer:
    """A face's ``render_mode`` at work: ``render()``'s value, and the window of ``"human"``
    updated after each reset and step."""

    def __init__(self, render_frame: Any, render_mode: str | None, fps: float, title: str) -> None:
        self._frame = render_frame
        """Zero-argument callable giving the current frame (the arena's ``render``)."""
        self.render_mode = render_mode
        self.window = Window(title, fps) if render_mode == HUMAN else None

    def render(self) -> np.ndarray | None:
        """The frame for ``"rgb_array"``; None (and a warning) without a render mode; None for
        ``"human"``, whose window is already up to date."""
        if self.render_mode == RGB_ARRAY:
            return np.asarray(self._frame(), dtype=np.uint8)
        if self.render_mode is None:
            import gymnasium

            gymnasium.logger.warn(
                "render() was called without a render_mode; build with render_mode='rgb_array'"
            )
        return None

    def update(self) -> None:
        """After a reset or step: show the new frame in the ``"human"`` window."""
        if self.window is not None:
            self.window.show(np.asarray(self._frame(), dtype=np.uint8))

    def close(self) -> None:
        if self.window is not None:
            self.window.close()
