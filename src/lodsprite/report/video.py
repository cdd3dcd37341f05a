"""Videos of rendered paths (``lodsprite render --video FILE.mp4``).

Frames go to an H.264 MP4 through imageio's FFmpeg plugin (imageio-ffmpeg ships the
``ffmpeg`` binary in its wheel).  Like every output of lodsprite a video is written
atomically: frames stream into a hidden temporary file beside the target, which replaces
the target only when the last frame is in; a failed or interrupted run leaves no
half-written video.

With ground truth a frame is three panels side by side: full resolution | the frame
shown | their absolute difference, amplified by :data:`DIFF_GAIN`.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from lodsprite.errors import InputError
from lodsprite.files import FILE_MODE

VIDEO_SUFFIXES = (".mp4",)
DEFAULT_FPS = 30
DIFF_GAIN = 4.0
"""The difference panel shows ``|full - shown| * DIFF_GAIN`` (clipped to 255)."""


def check_video_path(path: Path) -> Path:
    """``path`` if it names an MP4 file lodsprite can write; raises :class:`InputError`."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"--video must name an .mp4 file, got '{path}'")
    if path.is_dir():
        raise InputError(f"--video names a folder: '{path}'")
    return path


def side_by_side(truth: np.ndarray, shown: np.ndarray) -> np.ndarray:
    """``(H, 3W, 3) uint8``: ``truth | shown | |truth - shown| * DIFF_GAIN`` from two
    ``(H, W, 3) uint8`` images."""
    diff = np.abs(truth.astype(np.int16) - shown.astype(np.int16)) * DIFF_GAIN
    return np.concatenate([truth, shown, np.clip(diff, 0, 255).astype(np.uint8)], axis=1)


def _even(image: np.ndarray) -> np.ndarray:
    """Pad ``(H, W, 3)`` to even sides by repeating the last row/column (H.264 with
    4:2:0 chroma needs even sides)."""
    h, w = image.shape[:2]
    return np.pad(image, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


class VideoWriter:
    """Write ``(H, W, 3) uint8`` frames (all the same size) to an MP4 atomically.

    Use as a context manager: the file appears at ``path`` on a clean exit only.
    """

    def __init__(self, path: Path, fps: int = DEFAULT_FPS) -> None:
        self.path = check_video_path(path)
        self.fps = int(fps)
        self.frames = 0
        self._writer = None
        self._tmp: Path | None = None
        self._shape: tuple[int, ...] | None = None

    def __enter__(self) -> VideoWriter:
        import imageio.v2 as imageio

        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.stem}.",
                                   suffix=".mp4")
        os.close(fd)
        self._tmp = Path(tmp)
        # macro_block_size=1: no resizing to multiples of 16 (sides are padded to even).
        self._writer = imageio.get_writer(self._tmp, format="FFMPEG", mode="I", fps=self.fps,
                                          codec="libx264", quality=8, macro_block_size=1,
                                          ffmpeg_log_level="error")
        return self

    def append(self, image: np.ndarray) -> None:
        """Add one frame, ``(H, W, 3) uint8``, row 0 at the top."""
        if self._writer is None:
            raise RuntimeError("VideoWriter.append outside its 'with' block")
        image = _even(np.ascontiguousarray(image, dtype=np.uint8))
        if self._shape is None:
            self._shape = image.shape
        elif image.shape != self._shape:
            raise ValueError(f"frame {self.frames} is {image.shape}, expected {self._shape}")
        self._writer.append_data(image)
        self.frames += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if self._writer is not None:
                self._writer.close()
            if exc_type is None and self.frames > 0:
                os.chmod(self._tmp, FILE_MODE)
                os.replace(self._tmp, self.path)
        finally:
            if self._tmp is not None:
                self._tmp.unlink(missing_ok=True)
