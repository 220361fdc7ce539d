"""The one reader of a capture's frames (aat-infer's run, `aat_deploy.api.read_stack`, aat-diagnose's inputs):
the frame files, near to far, decoded on demand to linear RGB (H, W, 3) float32 by `aat_deploy.capture.raw.load_frame`
(kind from content, the pixel limit checked before decoding), every frame checked to be the first one's size."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..capture.raw import load_frame
from ..errors import CaptureError


class FrameReader:
    """Decoders of the frame files `paths` (in the stack's order). `decoder(i)` decodes frame i when called (the
    pipeline streams them); `first_hw()` decodes the first frame once to learn the size and keeps it for its
    decoder; `read_all()` decodes every frame. info[i]: what the reader reported for frame i (RAW development)."""

    def __init__(self, paths: list[Path], max_megapixels: float | None = None):
        self.paths = [Path(p) for p in paths]
        self.max_megapixels = max_megapixels
        self.info: dict[int, dict] = {}
        self._hw: tuple[int, int] | None = None
        self._kept: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.paths)

    def decode(self, i: int) -> np.ndarray:
        """Frame i as (H, W, 3) float32 linear RGB; CaptureError naming the file if it is not the first one's size."""
        if i == 0 and self._kept is not None:
            img, self._kept = self._kept, None
            return img
        img, info = load_frame(self.paths[i], self.max_megapixels)
        if self._hw is None:
            self._hw = img.shape[:2]
        elif img.shape[:2] != self._hw:
            h0, w0 = self._hw
            raise CaptureError(f"{self.paths[i]}: frame is {img.shape[1]}x{img.shape[0]} px, {self.paths[0].name} is "
                               f"{w0}x{h0}: frames of different sizes")
        if info:
            self.info.setdefault(i, info)
        return img

    def decoder(self, i: int) -> Callable[[], np.ndarray]:
        return lambda: self.decode(i)

    def decoders(self) -> list[Callable[[], np.ndarray]]:
        return [self.decoder(i) for i in range(len(self))]

    def first_hw(self) -> tuple[int, int]:
        """(H, W) of the frames: the first frame decoded (and kept for its decoder) if none was yet."""
        if self._hw is None:
            self._kept = self.decode(0)
        return self._hw

    def frames(self) -> Iterator[np.ndarray]:
        """Every frame in order, one at a time."""
        for i in range(len(self)):
            yield self.decode(i)

    def read_all(self) -> np.ndarray:
        """(S, H, W, 3) float32: every frame."""
        return np.stack(list(self.frames()))
