"""``render_mode="human"`` without a display: the window logic against a stand-in Tk.

The real window needs a display (tests/client/test_gym_env.py runs it where there is one);
here ``tkinter`` and Pillow's ``ImageTk`` are replaced by recorders, so what the faces ask
of a window (open on the first frame, one frame per reset and step, the arena's frame, kept
to ``render_fps``, closed with the environment) is checked on any machine.
"""

from __future__ import annotations

import sys
import time
import types
from typing import Any, ClassVar

import gymnasium
import numpy as np
import PIL
import pytest

import neuronsmae.client  # noqa: F401  (registers the environments)
from neuronsmae.client.viewer import Window

IN_PROCESS = "neuronsmae.server:Arena"


class FakeTk:
    """Records what a Tk root is asked to do."""

    opened: ClassVar[list[FakeTk]] = []

    def __init__(self) -> None:
        self.title_text, self.updates, self.destroyed = "", 0, False
        FakeTk.opened.append(self)

    def title(self, text: str) -> None:
        self.title_text = text

    def update(self) -> None:
        self.updates += 1

    def destroy(self) -> None:
        self.destroyed = True


class FakeLabel:
    def __init__(self, root: FakeTk) -> None:
        self.root, self.images = root, []

    def pack(self) -> None:
        pass

    def configure(self, image: Any) -> None:
        self.images.append(image)


@pytest.fixture
def fake_tk(monkeypatch: pytest.MonkeyPatch) -> list[np.ndarray]:
    """Stand-ins for tkinter and ImageTk; returns the frames shown, in order."""
    shown: list[np.ndarray] = []
    tkinter = types.ModuleType("tkinter")
    tkinter.Tk = FakeTk  # type: ignore[attr-defined]
    tkinter.Label = FakeLabel  # type: ignore[attr-defined]
    tkinter.TclError = RuntimeError  # type: ignore[attr-defined]
    image_tk = types.ModuleType("PIL.ImageTk")
    image_tk.PhotoImage = lambda image: shown.append(np.asarray(image)) or image  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "tkinter", tkinter)
    monkeypatch.setitem(sys.modules, "PIL.ImageTk", image_tk)
    monkeypatch.setattr(PIL, "ImageTk", image_tk, raising=False)
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(FakeTk, "opened", [])
    return shown


def test_the_window_shows_the_arenas_frame_after_each_reset_and_step(
    fake_tk: list[np.ndarray],
) -> None:
    env = gymnasium.make(
        "NeuronsMAE/Coop-v0", env=IN_PROCESS, render_mode="human", episode_steps=200
    )
    frames = gymnasium.make(
        "NeuronsMAE/Coop-v0", env=IN_PROCESS, render_mode="rgb_array", episode_steps=200
    )
    try:
        assert not FakeTk.opened  # nothing opens before the first frame
        env.reset(seed=3)
        frames.reset(seed=3)
        action = env.action_space.sample()
        env.step(action)
        frames.step(action)
        assert env.render() is None  # the window is up to date by itself
        (root,) = FakeTk.opened
        assert root.updates == len(fake_tk) == 2 and "NeuronsMAE" in root.title_text
        np.testing.assert_array_equal(fake_tk[-1], frames.render())
    finally:
        env.close()
        frames.close()
    assert root.destroyed


def test_frames_are_kept_to_the_frame_rate(fake_tk: list[np.ndarray]) -> None:
    window = Window("paced", fps=20.0)
    frame = np.zeros((4, 6, 3), np.uint8)
    start = time.monotonic()
    for _ in range(4):
        window.show(frame)
    assert time.monotonic() - start >= 3 * 0.05 * 0.95  # three waits of 1/20 s at least
    assert window.is_open and len(fake_tk) == 4
    window.close()
    window.close()  # safe to repeat
    assert not window.is_open and FakeTk.opened[0].destroyed
