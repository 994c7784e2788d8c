"""NanoTrack v2, a small learned tracker, as the guide of the ``fused`` preset (:class:`sptpt.tracker.Guide`).

OpenCV's ``TrackerNano`` runs the weights shipped in ``annotator/data/nanotrack_v2`` (Apache-2.0, see the NOTICE
and LICENSE there), loaded by path, never downloaded. It follows the object from the first box on its own; SPTPT
draws candidates around its box and its own models choose (``TrackerParams.guide_particles``).

Its state lives inside OpenCV and cannot be copied, so a copy (a checkpoint) keeps how far it got instead, and is
brought back there by :meth:`NanoTrackGuide.catch_up` with the same frames: its boxes depend on the frames alone, so
the replayed guide is the one that was saved, to the bit.
"""

from __future__ import annotations

from importlib import resources

import cv2
import numpy as np

__all__ = ["NanoTrackGuide", "nanotrack_weights"]


def nanotrack_weights() -> tuple[str, str]:
    """Paths of the shipped backbone and head ONNX files."""
    folder = resources.files("annotator") / "data" / "nanotrack_v2"
    return str(folder / "backbone.onnx"), str(folder / "head.onnx")


class NanoTrackGuide:
    """OpenCV's TrackerNano with the shipped weights, on RGB frames, one OpenCV thread."""

    def __init__(self) -> None:
        self._tracker = _new_tracker()
        self._first_box: np.ndarray | None = None
        self._seen = 0  # frames the OpenCV tracker has had, the first included
        self._saved = 0  # a restored copy: frames the saved guide had had (0: not restored)

    def init(self, rgb: np.ndarray, box_xywh: np.ndarray) -> None:
        box = np.asarray(box_xywh, dtype=np.float64)
        # OpenCV takes an integer rectangle; at least one pixel each way.
        rect = tuple(int(round(v)) for v in box[:2]) + tuple(max(1, int(round(v))) for v in box[2:])
        self._tracker.init(_bgr(rgb), rect)
        self._first_box, self._seen, self._saved = box.copy(), 1, 0

    def update(self, rgb: np.ndarray) -> tuple[np.ndarray, float]:
        if self.behind:
            raise RuntimeError(f"this NanoTrack guide was restored from a copy {self._saved} frames in: give "
                               f"catch_up() the first {self.behind} frames first")
        return self._step(rgb)

    @property
    def behind(self) -> int:
        """Frames (the first included) that :meth:`catch_up` still needs; 0 when it can go on."""
        return self._saved - self._seen if self._saved else 0

    def catch_up(self, rgb: np.ndarray) -> None:
        """Bring a restored copy one frame nearer to where it was saved: give it the video's frames from the
        first, in order (RGB), until :attr:`behind` is 0."""
        if not self.behind:
            raise RuntimeError("catch_up() on a NanoTrack guide that is not behind")
        if self._seen == 0:
            saved = self._saved
            assert self._first_box is not None  # behind: it was saved after init
            self.init(rgb, self._first_box)
            self._saved = saved
        else:
            self._step(rgb)
        if self._seen == self._saved:
            self._saved = 0  # caught up

    def _step(self, rgb: np.ndarray) -> tuple[np.ndarray, float]:
        found, rect = self._tracker.update(_bgr(rgb))
        self._seen += 1
        box = np.asarray(rect, dtype=np.float64) if found else np.full(4, np.nan)
        return box, float(self._tracker.getTrackingScore())

    def __getstate__(self) -> dict:
        return {"first_box": self._first_box, "frames": self._seen + self.behind}

    def __setstate__(self, state: dict) -> None:
        self._tracker = _new_tracker()
        self._first_box, self._seen, self._saved = state["first_box"], 0, state["frames"]


def _new_tracker():
    cv2.setNumThreads(1)  # its share of the cores: SPTPT's runs use them
    params = cv2.TrackerNano_Params()
    params.backbone, params.neckhead = nanotrack_weights()
    # OpenCV's DNN warns, on every load, that its new graph engine ignores the target it is given: noise to a user.
    # (OpenCV 4.x has no cv2.utils.logging, nor that warning.)
    logging = getattr(cv2.utils, "logging", None)
    if logging is None:
        return cv2.TrackerNano_create(params)
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_ERROR)
    try:
        return cv2.TrackerNano_create(params)
    finally:
        logging.setLogLevel(level)


def _bgr(rgb: np.ndarray) -> np.ndarray:
    """The frame in OpenCV's channel order, a new array.

    ``cvtColor``, not ``np.ascontiguousarray(rgb[:, :, ::-1])``: the same pixels, but numpy copies a reversed
    channel axis one byte at a time, 9 ms a 1920x1080 frame against 0.2 ms (issue #69: cost that grew with the frame).
    """
    return cv2.cvtColor(rgb, cv2.COLOR_GRAY2BGR if rgb.ndim == 2 else cv2.COLOR_RGB2BGR)


def guide_for(params) -> NanoTrackGuide | None:
    """A new NanoTrack guide where ``params`` (a :class:`sptpt.TrackerParams`) use one, else None."""
    return NanoTrackGuide() if params.uses_guide else None
