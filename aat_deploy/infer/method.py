"""What a depth method is to the runtime: `DepthMethod`, the one interface of the classical focus method
(`aat_deploy.focus.runner.FocusMethod`), the lens-specific ONNX DfF model (`aat_deploy.infer.model.DfFModel`) and the
any-camera model (`aat_deploy.anycam.model.FocusMapModel`); `DepthOutput`, what each returns for one stack.

The capture pipeline (`aat_deploy.infer.pipeline.run_capture`), the array part (`aat_deploy.infer.process.depth_from_frames`),
the Python API (`aat_deploy.api.depth_from_focus`) and aat-eval's datasets ask a method only what is declared here;
a method says what it does differently through these attributes and methods, never through its class or kind.
Distances in metres from the sensor plane; sizes (W, H) or (H, W) in pixels as named.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import CaptureError
from ..optics.camera import Intrinsics


@dataclass
class DepthOutput:
    """One stack's maps at the working size: depth_m (H, W) metres from the sensor; aif (3, H, W) the all-in-focus
    image in the stack's normalised units; std_m (H, W) the uncertainty (metres); confidence (H, W) in [0, 1] (the
    chance that the depth is within the calibration's tolerance, `aat_deploy.confidence`) or None without a
    calibration; all float32. warnings: one line each; info: what the method reports about itself (settings)."""

    depth_m: np.ndarray
    aif: np.ndarray
    std_m: np.ndarray
    confidence: np.ndarray | None = None
    warnings: list[str] = field(default_factory=list)
    info: dict | None = None


class DepthMethod(ABC):
    """A focal stack's depth method, as the runtime drives it.

    Attributes every method sets: stack_range (min, max) frames; focus_range_m (near, far) it is meant for;
    lens_name, focal_length_mm, f_number of the lens it assumes (None: unknown, nothing to compare the EXIF with).
    """

    noun = "model"  # what one-line messages call it ("the model takes 2..16 frames")
    places_tied_frames = False  # frames with equal reported focus are placed by the method (else refused)
    auto = False  # the working size is chosen from the stack itself (tile_sampler, pre_reduction, choose_size)
    stack_range: tuple[int, int]
    focus_range_m: tuple[float, float]
    lens_name: str | None = None
    focal_length_mm: float | None = None
    f_number: float | None = None

    # -- before a stack runs -----------------------------------------------------------------------------------
    def for_capture(self, capture, frame_hw: Callable[[], tuple[int, int]]) -> DepthMethod:
        """The method for this capture folder (`aat_deploy.capture.folder.Capture`); frame_hw() decodes the
        first frame if needed and returns its (H, W). Default: itself (it needs nothing of the capture)."""
        return self

    def for_arrays(self, frame_hw: tuple[int, int], focus_m: np.ndarray, *, camera=None, lens=None, psf=None,
                   calibration=None) -> DepthMethod:
        """The method for frames given as arrays (the Python API): camera (focal mm, f-number, pixel um) or the
        text "F,N,PIXEL_UM", or a lens / PSF / calibration file, where the method takes one. Default: none taken
        (CaptureError naming what was given)."""
        given = [n for n, v in (("camera", camera), ("lens", lens), ("psf", psf), ("calibration", calibration))
                 if v is not None]
        if given:
            raise CaptureError(f"{self.describe()}: {', '.join(given)} belong to the any-camera model "
                               "(model='dfv_aat') and the classical method (method='focus')")
        return self

    def describe(self) -> str:
        """What the method is, for one-line messages."""
        return f"this {self.noun}"

    def frame_warnings(self, frame_hw: tuple[int, int], where) -> list[str]:
        """Warnings about frames of this (H, W) (one line each, naming `where`). Default: none."""
        return []

    @abstractmethod
    def working_size(self, frame_hw: tuple[int, int]) -> tuple[int, int]:
        """(W, H) the frames of (H, W) are brought to (when not `auto`)."""

    def tile_sampler(self, frame_hw: tuple[int, int]):
        """What cuts the tiles choose_size reads from each native frame of (H, W): `.sample(frame)` -> a list over
        pyramid levels of (N, R, R) arrays (`auto` methods only)."""
        raise NotImplementedError(f"{type(self).__name__} chooses no working size from the stack")

    def pre_reduction(self, frame_hw: tuple[int, int]) -> tuple[int, int]:
        """(W, H) to keep frames at until choose_size has seen them (`auto` methods only)."""
        raise NotImplementedError(f"{type(self).__name__} chooses no working size from the stack")

    def choose_size(self, frame_hw: tuple[int, int], levels: list[np.ndarray]) -> tuple[tuple[int, int], dict]:
        """(W, H) from the frames' tiles, and what summary.json says of the choice (`auto` methods only)."""
        raise NotImplementedError(f"{type(self).__name__} chooses no working size from the stack")

    # -- running ---------------------------------------------------------------------------------------------
    @abstractmethod
    def infer(self, stack: np.ndarray, focus_m: np.ndarray, tile: int | None = None, progress=None) -> DepthOutput:
        """stack (S, 3, H, W) float32 normalised (docs/contracts.md), frames near to far; focus_m (S,) metres,
        ascending; tile: run in tiles of this many px where the method can; progress(done, total) for tiles.
        CaptureError (one line) for a stack it cannot take."""

    @abstractmethod
    def intrinsics(self, size_wh: tuple[int, int]) -> Intrinsics:
        """Pinhole intrinsics of maps of size_wh = (W, H) (`aat_deploy.optics.camera`)."""

    @abstractmethod
    def summary(self) -> dict:
        """What summary.json records of the method (JSON-serialisable)."""
