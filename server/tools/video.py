"""Frames to a GIF (core dependencies only: Pillow) or an MP4 (imageio with the ``video`` extra).

Why GIF by default: it needs nothing beyond the core dependencies and plays inline in a
README, an issue or a notebook. MP4 is smaller and sharper but needs an ffmpeg binary,
which ``imageio-ffmpeg`` ships: ``pip install 'neuronsmae[video]'``.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from neuronsmae.protocol.errors import InvalidOptionError, MissingDependencyError

DEFAULT_FPS = 5.0
"""Frames per second: one frame per 0.4 s decision at 5 fps plays at twice real time."""
FPS_RANGE = (0.1, 50.0)
"""Frame rates a video may have. A GIF's delays are whole hundredths of a second and most
viewers play any delay under two of them as ten, so above 50 fps a GIF plays slower, not
faster; below 0.1 fps one frame stays on screen for ten seconds."""
SCALE_RANGE = (0.05, 4.0)
"""Factors a frame may be resized by (the renderer's frames are a few hundred pixels wide)."""


def check_video_options(fps: float = DEFAULT_FPS, every: int = 1, scale: float = 1.0) -> None:
    """Refuse a frame rate, frame step or scale outside its range, naming every one that is
    (NaN is outside every range)."""
    problems = []
    if not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:
        problems.append(f"fps must be in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}], got {fps}")
    if not every >= 1:
        problems.append(f"every must be an integer ≥ 1, got {every}")
    if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
        problems.append(f"scale must be in [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}], got {scale}")
    if problems:
        raise InvalidOptionError("; ".join(problems))


def prepare(frames: Sequence[np.ndarray], every: int = 1, scale: float = 1.0) -> list[np.ndarray]:
    """Every ``every``-th frame (the last one always kept: it shows the result), resized by
    ``scale``."""
    check_video_options(every=every, scale=scale)
    if not frames:
        raise InvalidOptionError("no frames to write")
    keep = list(range(0, len(frames), every))
    if keep[-1] != len(frames) - 1:
        keep.append(len(frames) - 1)
    out = []
    for i in keep:
        frame = np.asarray(frames[i], dtype=np.uint8)
        if scale != 1.0:
            h, w = frame.shape[:2]
            size = (max(2, round(w * scale)), max(2, round(h * scale)))
            frame = np.asarray(
                Image.fromarray(frame).resize(size, Image.Resampling.LANCZOS, reducing_gap=2.0)
            )
        out.append(frame)
    return out


PALETTE_SAMPLES = 8
"""Frames the GIF palette is built from (spread over the episode)."""


def write_gif(path: str | Path, frames: Sequence[np.ndarray], fps: float = DEFAULT_FPS) -> Path:
    """Write an endlessly looping GIF with one palette for every frame; return its path.

    Why Pillow directly rather than through imageio: imageio's GIF writer has Pillow build
    a palette per frame (median cut), ten times slower than mapping every frame onto one
    palette, and a palette that changes from frame to frame makes colours flicker. The
    renderer draws with a dozen colours, so one palette built from a few frames fits all.
    """
    check_video_options(fps)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    picks = np.linspace(0, len(frames) - 1, min(PALETTE_SAMPLES, len(frames))).round()
    sample = Image.fromarray(np.concatenate([frames[int(i)] for i in picks], axis=0))
    palette = sample.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    images = [
        Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames
    ]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                   duration=round(1000 / fps), loop=0)  # fmt: skip
    return path


def check_writable(path: str | Path) -> None:
    """Refuse a video name or a missing backend before any frame is drawn, so a long replay
    is not run only to fail at the end."""
    suffix = Path(path).suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InvalidOptionError(f"video {path}: the name must end in .gif or .mp4")
    if suffix == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise MissingDependencyError(
            "writing MP4 needs imageio-ffmpeg: pip install 'neuronsmae[video]' "
            "(GIF works without it)"
        )


def write_mp4(path: str | Path, frames: Sequence[np.ndarray], fps: float = DEFAULT_FPS) -> Path:
    """Write an H.264 MP4 (needs imageio-ffmpeg); return its path."""
    check_writable(path)
    check_video_options(fps)
    import imageio.v2 as iio2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with iio2.get_writer(
        path,
        format="FFMPEG",
        mode="I",
        fps=fps,
        codec="libx264",
        pixelformat="yuv420p",
        macro_block_size=1,
    ) as writer:
        for frame in frames:
            h, w = frame.shape[:2]  # yuv420p needs even sides: pad by one row/column
            writer.append_data(np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge"))
    return path


def write_video(
    path: str | Path,
    frames: Sequence[np.ndarray],
    fps: float = DEFAULT_FPS,
    every: int = 1,
    scale: float = 1.0,
) -> Path:
    """GIF or MP4 by the file's suffix, after :func:`prepare`."""
    check_writable(path)
    check_video_options(fps, every, scale)
    kept = prepare(frames, every, scale)
    if Path(path).suffix.lower() == ".gif":
        return write_gif(path, kept, fps)
    return write_mp4(path, kept, fps)
