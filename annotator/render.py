"""The overlay video: tracker output drawn on the frames, streamed to an H.264 MP4.

Two parts with one job each (the supervision annotator pattern):

* :class:`OverlayRenderer` is stateless and configured once: ``annotate(frame,
  items)`` returns a new frame with the layers drawn (particle cloud,
  superpixel boundaries, boxes with labels, the review mark).
* :class:`OverlayWriter` streams frames to ``ffmpeg`` as they come, so memory
  does not grow with the video, and publishes the file only when it is
  complete (atomic rename).

Frames are RGB ``uint8``; OpenCV's drawing functions do not care about
channel order as long as colours are given as RGB tuples, which they are here.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import subprocess
import sys
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import IO, Literal, Sequence, cast

import cv2
import imageio_ffmpeg
import numpy as np

from annotator.atomic import atomic_path
from annotator.tracks import KEYFRAME_GIVEN, TrackResult
from sptpt import checked_box, checked_particles
from sptpt.boxes import xywh_to_xyxy

__all__ = ["DEFAULT_PALETTE", "OverlayItem", "OverlayRenderer", "OverlayWriter", "i420_to_rgb", "items_from_tracks",
           "label_text", "rgb_to_i420"]

RGB = tuple[int, int, int]

#: Box colours by track id (tab10 without its red and green, which mark flags and corrections).
DEFAULT_PALETTE: tuple[RGB, ...] = (
    (31, 119, 180),
    (255, 127, 14),
    (148, 103, 189),
    (23, 190, 207),
    (227, 119, 194),
    (188, 189, 34),
    (140, 86, 75),
    (127, 127, 127),
)


@dataclass(frozen=True)
class OverlayItem:
    """What to draw for one track on one frame.

    Attributes
    ----------
    box_xywh : (4,) float64 ndarray
        0-based ``x, y, w, h``; a NaN box draws nothing but its review mark.
    track_id : int
    confidence : float
        In [0, 1]; shown in the label.
    flagged : bool
        The frame needs review: draws the red border and ``REVIEW`` tag.
    keyframe_source : str
        Who gave the box, as in :attr:`TrackResult.keyframe_source`:
        :data:`~annotator.tracks.KEYFRAME_GIVEN` for the user's first-frame
        box (drawn thicker in the track colour, labelled ``given``),
        ``FILE:LINE`` of a human correction (drawn thicker in the corrected
        colour, labelled ``corrected``), ``""`` for a tracker box.
    particles_xywh : (N, 4) ndarray or None
        Candidate boxes; their centres are drawn as dots.
    particle_scores : (N,) ndarray or None
        Candidate scores; dots are shaded by score normalised over this
        item's particles on this frame (dark = worst, bright = best), since
        only the ranking within one frame and track is meaningful.
    superpixel_labels : (h, w) int ndarray or None
        Labels of the winning candidate's superpixels, -1 outside it.
    superpixel_origin_xy : (2,) int ndarray or None
        Frame column and row of ``superpixel_labels[0, 0]``.
    """

    box_xywh: np.ndarray
    track_id: int
    confidence: float
    flagged: bool = False
    keyframe_source: str = ""
    particles_xywh: np.ndarray | None = None
    particle_scores: np.ndarray | None = None
    superpixel_labels: np.ndarray | None = None
    superpixel_origin_xy: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "box_xywh", checked_box(self.box_xywh, "OverlayItem: "))
        if not isinstance(self.keyframe_source, str):
            raise ValueError(f"OverlayItem.keyframe_source must be a string ('{KEYFRAME_GIVEN}', 'FILE:LINE' or ''), "
                             f"got {self.keyframe_source!r}")
        particles, scores = checked_particles(self.particles_xywh, self.particle_scores, "OverlayItem: ")
        object.__setattr__(self, "particles_xywh", particles)
        object.__setattr__(self, "particle_scores", scores)
        if (self.superpixel_labels is None) != (self.superpixel_origin_xy is None):
            raise ValueError("OverlayItem: superpixel_labels and superpixel_origin_xy come together or not at all")
        if self.superpixel_labels is not None:
            labels = np.asarray(self.superpixel_labels)
            origin = np.asarray(self.superpixel_origin_xy)
            if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer) or origin.shape != (2,):
                raise ValueError(
                    f"OverlayItem: superpixel_labels must be an (h, w) integer array and superpixel_origin_xy (2,), "
                    f"got {labels.dtype} {labels.shape} and {origin.shape}"
                )
            object.__setattr__(self, "superpixel_labels", labels)
            object.__setattr__(self, "superpixel_origin_xy", origin.astype(np.int64))

    @property
    def given(self) -> bool:
        """The box is the user's first-frame box."""
        return self.keyframe_source == KEYFRAME_GIVEN

    @property
    def corrected(self) -> bool:
        """The box is a human correction (a keyframe other than the given first-frame box)."""
        return self.keyframe_source not in ("", KEYFRAME_GIVEN)

    @classmethod
    def from_frame_result(cls, result, *, track_id: int, flagged: bool = False, keyframe_source: str = "",
                          confidence: float | None = None) -> OverlayItem:
        """Item from a :class:`sptpt.results.FrameResult` (particles and superpixels when it has them);
        ``confidence`` replaces the tracker's (the tool shows ``1 - p_fail``)."""
        return cls(
            box_xywh=result.box_xywh,
            track_id=track_id,
            confidence=result.confidence if confidence is None else confidence,
            flagged=flagged,
            keyframe_source=keyframe_source,
            particles_xywh=result.particles_xywh,
            particle_scores=result.particle_scores,
            superpixel_labels=result.superpixel_labels,
            superpixel_origin_xy=result.superpixel_origin_xy,
        )


def items_from_tracks(tracks: Sequence[TrackResult], frame_index: int) -> list[OverlayItem]:
    """Items of every track that has a row for source frame ``frame_index`` (boxes only).

    For re-rendering an overlay from saved tracks, e.g. after review.
    Frames where the object is ``outside`` keep their review mark but no box.
    """
    items = []
    for track in tracks:
        row = int(np.searchsorted(track.frame_indices, frame_index))
        if row < len(track) and track.frame_indices[row] == frame_index:
            box = np.full(4, np.nan) if track.outside[row] else track.boxes_xywh[row]
            items.append(
                OverlayItem(
                    box_xywh=box,
                    track_id=track.track_id,
                    confidence=float(track.confidence[row]),
                    flagged=bool(track.flagged[row]),
                    keyframe_source=track.keyframe_source[row],
                )
            )
    return items


def label_text(item: OverlayItem) -> str:
    """The text of an item's box label: ``id 1 0.87`` for a tracker box, ``id 1 given`` / ``id 1 corrected`` for a
    human one.

    A human box has no tracker confidence worth showing (it is 1 by
    definition), so its label names who gave it instead; short labels also
    keep small frames readable.
    """
    if item.given:
        return f"id {item.track_id} given"
    if item.corrected:
        return f"id {item.track_id} corrected"
    return f"id {item.track_id} {item.confidence:.2f}"


def _box_edges(out: np.ndarray, corners, colour: RGB, width: int, *, grow: int = 0) -> None:
    """Draw a box's four edges exactly ``width + 2 * grow`` pixels wide, centred on its outermost pixels.

    ``cv2.rectangle`` draws ``2 * (t // 2) + 1`` pixels for a thickness
    ``t``, so even widths would silently become odd; filled strips give the
    width asked for, with crisp axis-aligned pixels that show the box extent.
    """
    (x0, y0), (x1, y1) = corners
    before, after = (width - 1) // 2 + grow, width // 2 + grow
    for p0, p1 in (
        ((x0 - before, y0 - before), (x1 + after, y0 + after)),  # top
        ((x0 - before, y1 - before), (x1 + after, y1 + after)),  # bottom
        ((x0 - before, y0 - before), (x0 + after, y1 + after)),  # left
        ((x1 - before, y0 - before), (x1 + after, y1 + after)),  # right
    ):
        cv2.rectangle(out, p0, p1, colour, cv2.FILLED, cv2.LINE_8)


def _as_rgb(colour: RGB) -> RGB:
    """``colour`` as a tuple of plain ints, whatever sequence and number types it was given as."""
    return cast(RGB, tuple(int(c) for c in colour))  # the given colour's length, which RGB says is 3


def _text_colour(background: RGB) -> RGB:
    """Black or white, whichever contrasts more with ``background`` (WCAG 2 relative luminance).

    A fixed luma threshold put white text on the bright corrected green,
    which is hard to read at small sizes; the contrast ratio decides right.
    """
    channels = np.asarray(background, dtype=np.float64) / 255.0
    linear = np.where(channels <= 0.04045, channels / 12.92, ((channels + 0.055) / 1.055) ** 2.4)
    luminance = float(linear @ [0.2126, 0.7152, 0.0722])
    # Contrast ratios (L1 + 0.05) / (L2 + 0.05) against white (L = 1) and black (L = 0).
    return (0, 0, 0) if (luminance + 0.05) / 0.05 > 1.05 / (luminance + 0.05) else (255, 255, 255)


#: Shorter frame side (pixels) at which marks have their base size (320x240); larger frames scale them.
BASE_SIDE = 240


@dataclass(frozen=True)
class _Sizes:
    """Mark sizes for one frame size (see :meth:`OverlayRenderer.sizes_for`)."""

    thickness: int  # box line width, pixels
    font_scale: float  # cv2 Hershey scale of label text
    font_weight: int  # text stroke width, pixels
    particle_radius: int  # dot radius, pixels (0 = one pixel)


class OverlayRenderer:
    """Draws tracker output on RGB frames; stateless, configured in the constructor.

    Sizes follow the frame: with ``s = min(H, W) / 240`` (1 for 320x240,
    3 for 1280x720), boxes are ``round(s)`` pixels wide (at least 2, so a
    box reads against a busy background at 320x240), label
    text has scale ``max(0.4, 0.3 s)`` (0.4 is the smallest Hershey size
    that stays readable) and particle dots have radius ``round((s - 1) / 2)``
    (single pixels up to 480p), unless given explicitly. Drawing is
    deterministic: the same frame and items give the same pixels.

    Parameters
    ----------
    palette : sequence of RGB tuples
        Box colours, chosen by ``track_id`` (cycled).
    corrected_color : RGB tuple
        Colour of human-corrected boxes (the given first-frame box keeps its track colour).
    flag_color : RGB tuple
        Colour of the review border and tag.
    outline_color : RGB tuple or None
        A one-pixel line drawn on both sides of each box and around its label
        so they stand out on any background; None draws none.
    superpixel_color : RGB tuple
        Colour of superpixel boundaries.
    superpixel_alpha : float
        Opacity of superpixel boundaries in [0, 1]; faint by default, so the
        object stays visible under them.
    particle_colormap : int
        OpenCV colormap for particle dots (``cv2.COLORMAP_*``), dark = low score.
    particle_min_alpha : float
        Opacity in [0, 1] of the worst particle on a frame; opacity rises
        linearly to 1 for the best, so the cloud does not hide the object.
    particle_radius : int or None
        Dot radius in pixels (0 = single pixel); None scales with the frame.
    thickness : int or None
        Box line width; None scales with the frame. Human boxes are one pixel wider.
    font_scale : float or None
        Label text scale; None scales with the frame.
    draw_particles, draw_superpixels, draw_boxes, draw_labels, draw_flags : bool
        Which layers to draw.
    """

    def __init__(
        self,
        *,
        palette: Sequence[RGB] = DEFAULT_PALETTE,
        corrected_color: RGB = (0, 220, 0),
        flag_color: RGB = (230, 25, 25),
        outline_color: RGB | None = (0, 0, 0),
        superpixel_color: RGB = (255, 255, 255),
        superpixel_alpha: float = 0.3,
        particle_colormap: int = cv2.COLORMAP_VIRIDIS,
        particle_min_alpha: float = 0.35,
        particle_radius: int | None = None,
        thickness: int | None = None,
        font_scale: float | None = None,
        draw_particles: bool = True,
        draw_superpixels: bool = True,
        draw_boxes: bool = True,
        draw_labels: bool = True,
        draw_flags: bool = True,
    ) -> None:
        if not palette:
            raise ValueError("palette must hold at least one RGB colour")
        if not 0.0 <= superpixel_alpha <= 1.0:
            raise ValueError(f"superpixel_alpha must lie in [0, 1], got {superpixel_alpha}")
        if not 0.0 <= particle_min_alpha <= 1.0:
            raise ValueError(f"particle_min_alpha must lie in [0, 1], got {particle_min_alpha}")
        if particle_radius is not None and particle_radius < 0:
            raise ValueError(f"particle_radius must be >= 0 pixels or None for automatic, got {particle_radius}")
        if thickness is not None and thickness < 1:
            raise ValueError(f"thickness must be >= 1 pixel or None for automatic, got {thickness}")
        if font_scale is not None and not font_scale > 0:
            raise ValueError(f"font_scale must be > 0 or None for automatic, got {font_scale}")
        self.palette = tuple(_as_rgb(colour) for colour in palette)
        self.corrected_color = _as_rgb(corrected_color)
        self.flag_color = _as_rgb(flag_color)
        self.outline_color = None if outline_color is None else _as_rgb(outline_color)
        self.superpixel_color = np.asarray(superpixel_color, dtype=np.float32)
        self.superpixel_alpha = float(superpixel_alpha)
        self.particle_min_alpha = float(particle_min_alpha)
        self.particle_radius = particle_radius
        self.thickness = thickness
        self.font_scale = font_scale
        self.draw_particles = draw_particles
        self.draw_superpixels = draw_superpixels
        self.draw_boxes = draw_boxes
        self.draw_labels = draw_labels
        self.draw_flags = draw_flags
        # 256-entry RGB lookup table; applyColorMap returns BGR.
        ramp = np.arange(256, dtype=np.uint8).reshape(-1, 1)
        self._lut = cv2.applyColorMap(ramp, particle_colormap)[:, 0, ::-1].astype(np.float32)

    def color_for(self, track_id: int) -> RGB:
        """Box colour of a track."""
        return self.palette[(int(track_id) - 1) % len(self.palette)]

    def box_color(self, item: OverlayItem) -> RGB:
        """Colour of an item's box and label: the corrected colour for a correction, else the track's."""
        return self.corrected_color if item.corrected else self.color_for(item.track_id)

    def sizes_for(self, height: int, width: int) -> _Sizes:
        """Line width, text scale and dot radius used on an ``height`` x ``width`` frame."""
        unit = min(height, width) / BASE_SIDE
        font_scale = self.font_scale or max(0.4, 0.3 * unit)
        return _Sizes(
            thickness=self.thickness or max(2, round(unit)),
            font_scale=font_scale,
            font_weight=max(1, round(font_scale * 2)),
            particle_radius=(self.particle_radius if self.particle_radius is not None
                             else max(0, round((unit - 1) / 2))),
        )

    def annotate(self, frame_rgb: np.ndarray, items: Sequence[OverlayItem]) -> np.ndarray:
        """Draw ``items`` on a copy of ``frame_rgb``.

        Parameters
        ----------
        frame_rgb : (H, W, 3) uint8 ndarray
            The frame; not modified.
        items : sequence of OverlayItem
            One per track present on this frame.

        Returns
        -------
        (H, W, 3) uint8 ndarray
            A new C-contiguous frame.
        """
        frame = np.asarray(frame_rgb)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(f"frame_rgb must be an (H, W, 3) uint8 RGB array, got {frame.dtype} {frame.shape}")
        out = np.array(frame, dtype=np.uint8, order="C", copy=True)
        sizes = self.sizes_for(*out.shape[:2])

        # Layers from the back: particles, superpixels, boxes, labels, review mark.
        if self.draw_particles:
            for item in items:
                # Both or neither (OverlayItem checks); the test on the scores is for the type checker.
                if item.particles_xywh is not None and item.particle_scores is not None and len(item.particles_xywh):
                    self._particles(out, item.particles_xywh, item.particle_scores, sizes.particle_radius)
        if self.draw_superpixels:
            for item in items:
                if item.superpixel_labels is not None and item.superpixel_origin_xy is not None:
                    self._superpixels(out, item.superpixel_labels, item.superpixel_origin_xy)
        boxes = [(item, self._box_corners(item.box_xywh)) for item in items]
        if self.draw_boxes:
            for item, corners in boxes:
                if corners is not None:
                    line = self._line_width(item, sizes)
                    if self.outline_color is not None:
                        _box_edges(out, corners, self.outline_color, line, grow=1)
                    _box_edges(out, corners, self.box_color(item), line)
        if self.draw_labels:
            for item, corners in boxes:
                if corners is not None:
                    self._label(out, item, corners, sizes)
        if self.draw_flags:
            flagged = [item.track_id for item in items if item.flagged]
            if flagged:
                self._review_mark(out, flagged, sizes.font_scale)
        return out

    # ------------------------------------------------------------------ layers

    @staticmethod
    def _line_width(item: OverlayItem, sizes: _Sizes) -> int:
        return sizes.thickness + 1 if item.keyframe_source else sizes.thickness

    @staticmethod
    def _box_corners(box: np.ndarray) -> tuple[tuple[int, int], tuple[int, int]] | None:
        if not np.all(np.isfinite(box)):
            return None
        left, top, right, bottom = xywh_to_xyxy(box).tolist()
        # The box covers pixels x .. x+w-1; cv2 limits coordinates, so clamp far-away ones ourselves.
        x0, y0 = round(left), round(top)
        x1, y1 = round(right) - 1, round(bottom) - 1
        clamp = lambda v: int(min(max(v, -(1 << 15)), 1 << 15))  # noqa: E731
        return (clamp(x0), clamp(y0)), (clamp(max(x1, x0)), clamp(max(y1, y0)))

    def _particles(self, out: np.ndarray, particles: np.ndarray, scores: np.ndarray, radius: int) -> None:
        height, width = out.shape[:2]
        finite = np.isfinite(scores)
        shade = np.zeros(len(scores))
        if finite.any():
            lo, hi = scores[finite].min(), scores[finite].max()
            # One score for all particles (e.g. the first frame) says nothing about rank: mid shade.
            shade[finite] = (scores[finite] - lo) / (hi - lo) if hi > lo else 0.5
        centres = particles[:, :2] + particles[:, 2:] / 2.0
        keep = np.all(np.isfinite(centres), axis=1)
        order = np.argsort(shade[keep], kind="stable")  # best last, so it is drawn on top
        shade = shade[keep][order]
        cx = np.round(centres[keep, 0][order]).astype(np.int64)
        cy = np.round(centres[keep, 1][order]).astype(np.int64)
        dy, dx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
        disc = dx**2 + dy**2 <= radius * radius
        xs = (cx[:, None] + dx[disc][None, :]).ravel()
        ys = (cy[:, None] + dy[disc][None, :]).ravel()
        dot = np.repeat(np.arange(len(cx)), int(disc.sum()))
        inside = (xs >= 0) & (xs < width) & (ys >= 0) & (ys < height)
        xs, ys, dot = xs[inside], ys[inside], dot[inside]
        # Where dots overlap, the best one alone is blended (the last in draw order), so the result
        # does not depend on how numpy orders repeated writes.
        flat = ys * width + xs
        _, last = np.unique(flat[::-1], return_index=True)
        pick = len(flat) - 1 - last
        xs, ys, dot = xs[pick], ys[pick], dot[pick]
        alpha = (self.particle_min_alpha + (1.0 - self.particle_min_alpha) * shade[dot])[:, None]
        colours = self._lut[np.round(shade[dot] * 255).astype(np.int64)]
        blended = out[ys, xs].astype(np.float32) * (1.0 - alpha) + colours * alpha
        out[ys, xs] = np.clip(np.round(blended), 0, 255).astype(np.uint8)

    def _superpixels(self, out: np.ndarray, labels: np.ndarray, origin_xy: np.ndarray) -> None:
        height, width = out.shape[:2]
        labelled = labels >= 0
        # A boundary pixel differs from its right or lower neighbour, both inside the labelled
        # area; the outer edge of the window is left to the box.
        edge = np.zeros(labels.shape, dtype=bool)
        edge[:, :-1] |= (labels[:, :-1] != labels[:, 1:]) & labelled[:, :-1] & labelled[:, 1:]
        edge[:-1, :] |= (labels[:-1, :] != labels[1:, :]) & labelled[:-1, :] & labelled[1:, :]
        ox, oy = int(origin_xy[0]), int(origin_xy[1])
        fx0, fy0 = max(ox, 0), max(oy, 0)
        fx1, fy1 = min(ox + labels.shape[1], width), min(oy + labels.shape[0], height)
        if fx1 <= fx0 or fy1 <= fy0:
            return
        mask = edge[fy0 - oy : fy1 - oy, fx0 - ox : fx1 - ox]
        region = out[fy0:fy1, fx0:fx1]
        pixels = region[mask].astype(np.float32)
        blended = pixels * (1.0 - self.superpixel_alpha) + self.superpixel_color * self.superpixel_alpha
        region[mask] = np.clip(np.round(blended), 0, 255).astype(np.uint8)

    def _label(self, out: np.ndarray, item: OverlayItem, corners, sizes: _Sizes) -> None:
        text = label_text(item)
        colour = self.box_color(item)
        font = cv2.FONT_HERSHEY_SIMPLEX
        (tw, th), baseline = cv2.getTextSize(text, font, sizes.font_scale, sizes.font_weight)
        pad = max(2, th // 4)
        (x0, y0), (_, y1) = corners
        height, width = out.shape[:2]
        box_w, box_h = tw + 2 * pad, th + baseline + 2 * pad
        # How far the drawn edges reach outside the box's top and bottom rows (see _box_edges).
        line, grow = self._line_width(item, sizes), (1 if self.outline_color is not None else 0)
        reach_up, reach_down = (line - 1) // 2 + grow, line // 2 + grow
        left = min(max(x0 - reach_up, 0), max(width - box_w, 0))
        # Above the box when there is room, else below it, else just inside its top edge:
        # never over the object when it can be helped.
        top = y0 - reach_up - box_h
        if top < 0:
            top = y1 + reach_down + 1
            if top + box_h > height:
                top = max(y0 + reach_down + 1, 0)
        top = min(top, max(height - box_h, 0))
        if self.outline_color is not None:
            cv2.rectangle(out, (left - 1, top - 1), (left + box_w, top + box_h), self.outline_color, 1, cv2.LINE_8)
        cv2.rectangle(out, (left, top), (left + box_w - 1, top + box_h - 1), colour, cv2.FILLED)
        cv2.putText(out, text, (left + pad, top + pad + th), font, sizes.font_scale, _text_colour(colour),
                    sizes.font_weight, cv2.LINE_AA)

    def _review_mark(self, out: np.ndarray, track_ids: list[int], font_scale: float) -> None:
        height, width = out.shape[:2]
        border = max(3, math.ceil(min(height, width) / 100))
        c = self.flag_color
        out[:border], out[-border:], out[:, :border], out[:, -border:] = c, c, c, c
        text = "REVIEW" + (f" id {', '.join(str(t) for t in track_ids)}" if len(track_ids) > 1 else "")
        font = cv2.FONT_HERSHEY_SIMPLEX
        scale = font_scale * 1.2
        weight = max(1, round(font_scale * 2))
        (tw, th), baseline = cv2.getTextSize(text, font, scale, weight)
        if tw > width / 3:  # small frames: keep the tag from hiding the scene
            scale *= width / 3 / tw
            (tw, th), baseline = cv2.getTextSize(text, font, scale, weight)
        pad = max(3, th // 3)
        # Top right, so it does not sit on the labels, which hang from the boxes' top left.
        x1 = width - border
        x0 = max(x1 - tw - 2 * pad, 0)
        y0 = border
        cv2.rectangle(out, (x0, y0), (x1, y0 + th + baseline + 2 * pad), c, cv2.FILLED)
        cv2.putText(out, text, (x0 + pad, y0 + pad + th), font, scale, (255, 255, 255), weight, cv2.LINE_AA)


# U and V of BT.601 limited range (ITU-R BT.601, 8 bits: 16..240 around 128) from R, G, B and 1, for cv2.transform.
_RGB_TO_UV = np.array([[-37.797, -74.203, 112.0, 128 * 255], [112.0, -93.786, -18.214, 128 * 255]]) / 255


def rgb_to_i420(frame_rgb: np.ndarray) -> np.ndarray:
    """An ``(H, W, 3) uint8`` RGB frame as the ``(3 * H' / 2, W')`` uint8 planes of YUV 4:2:0 (I420: Y, then U and V
    at half size each way; BT.601, limited range, as FFmpeg converts RGB by default; each 2x2 block's chroma from
    its mean colour), ``H'`` and ``W'`` the even sizes the format needs: an odd frame is first padded by repeating
    its last row and/or column.

    Half the bytes of the RGB frame: how the frames waiting to be drawn are held (issue #69: at 1920x1080, 3 MiB a
    frame less). OpenCV's own I420 conversion takes each block's chroma from its top-left pixel alone, which loses
    or doubles a 1-pixel colour detail depending on where it falls; so only its Y plane is kept. (FFmpeg's own
    conversion filters the chroma over a few more pixels still.)
    """
    height, width = frame_rgb.shape[:2]
    if height % 2 or width % 2:
        frame_rgb = np.pad(frame_rgb, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
    frame_rgb = np.ascontiguousarray(frame_rgb)
    planes = cv2.cvtColor(frame_rgb, cv2.COLOR_RGB2YUV_I420)
    rows, cols = frame_rgb.shape[0] // 2, frame_rgb.shape[1] // 2
    block_means = cv2.resize(frame_rgb, (cols, rows), interpolation=cv2.INTER_AREA)  # exact 2x2 means, rounded
    chroma = cv2.transform(block_means, _RGB_TO_UV).reshape(rows, cols, 2)
    u_and_v = planes[2 * rows:].reshape(2, rows, cols)  # a view: U's plane, then V's
    u_and_v[0], u_and_v[1] = chroma[..., 0], chroma[..., 1]
    return planes


def i420_to_rgb(planes: np.ndarray, width: int, height: int) -> np.ndarray:
    """The ``(height, width, 3) uint8`` RGB frame of :func:`rgb_to_i420`'s planes (its padding cut off again).

    Not the frame that went in: each 2x2 block has one chroma and every value is rounded, about what the overlay's
    own encoding in 4:2:0 loses (about 41 dB of PSNR on a 1080p frame of OTB's David).
    """
    rgb = cv2.cvtColor(planes, cv2.COLOR_YUV2RGB_I420)
    return rgb if rgb.shape[:2] == (height, width) else np.ascontiguousarray(rgb[:height, :width])


# x264 options beside the preset and the rate. The encoder runs beside the tracker for the whole run, so its memory
# is part of the run's peak (issue #69). One thread: x264's frame threads (1.5 per core) each hold frames being
# encoded, and at ``ultrafast`` one thread encodes a 1080p frame in about 20 ms, a fifth of a tracked frame.
# Measured on 300 frames of 1920x1080 sent at 20 frames/s, crf 23: ``veryfast`` with x264's own threads (the
# default before) 290 MiB, 53 ms CPU a frame, 4.8 MiB of file, PSNR 42.7 dB; ``ultrafast`` with one thread 99 MiB,
# 20 ms, 9.2 MiB, 40.8 dB (``ultrafast`` has no look-ahead and no B-frames, which x264 holds frames for). The
# file is about twice as large; the CPU saved is the tracker's on a 2-core machine.
_ENCODER_OPTIONS = ("-threads", "1")
# ffmpeg turns the RGB frames into BT.601 limited-range YUV; the file says so. Untagged, players take HD video for
# BT.709 and show its colours slightly off (reds and greens most).
_COLOUR_TAGS = ("-colorspace", "smpte170m", "-color_range", "tv")
# The drawn frames go to the encoder as RGB, so that what is drawn (1-pixel particle dots, outlines, text) gets
# ffmpeg's own filtered 4:2:0 conversion. Sent as ``yuv420p`` converted here, the encoder held 7-8 MiB less at 1080p,
# but OpenCV's conversion is coarser on such details (HISTORY.md). Its queue options changed no memory.
# glibc's malloc in the encoder: a fixed mmap threshold (glibc's default value; setting it stops glibc from raising
# it). Each frame's buffers (6 MiB of RGB, 3 MiB of YUV) then go back to the system when freed. With the threshold
# raised, as glibc does after the first such buffer is freed, they stay in the heap of each of ffmpeg's threads:
# 96-98 -> 70 MiB at 1080p (ultrafast, one thread, 200 frames), for 1-3 ms more CPU a frame of page faults.
_ENCODER_MALLOC_TUNABLE = "glibc.malloc.mmap_threshold=131072"


def _encoder_environment() -> dict[str, str]:
    """The tool's environment with :data:`_ENCODER_MALLOC_TUNABLE` added to the user's own glibc tunables (a user's
    mmap threshold wins, in either of glibc's spellings). Other C libraries ignore the variable."""
    env = dict(os.environ)
    tunables = env.get("GLIBC_TUNABLES", "")
    if "glibc.malloc.mmap_threshold=" not in tunables and "MALLOC_MMAP_THRESHOLD_" not in env:
        env["GLIBC_TUNABLES"] = f"{tunables}:{_ENCODER_MALLOC_TUNABLE}" if tunables else _ENCODER_MALLOC_TUNABLE
    return env


def _encoder_process_group() -> dict:
    """Popen's arguments that put the encoder in a process group of its own, as imageio-ffmpeg puts its ffmpeg
    processes: a terminal's Ctrl-C then reaches the tool, which stops ffmpeg itself (``OverlayWriter.__exit__``),
    not ffmpeg, which would finish a partial file. None where imageio-ffmpeg's own switch,
    ``IMAGEIO_FFMPEG_NO_PREVENT_SIGINT``, is set: batch pool workers keep every ffmpeg in the run's group, so that
    a signal to the whole run (``kill -9 -PGID``) reaches them too (``annotator.batch.workers``)."""
    if os.environ.get("IMAGEIO_FFMPEG_NO_PREVENT_SIGINT", "").lower() not in ("", "0", "false", "no"):
        return {}
    if sys.platform == "win32":
        return {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP}
    return {"process_group": 0}


def _pipe_closed(err: OSError) -> bool:
    """Whether writing to ffmpeg failed because ffmpeg is gone (Windows says EINVAL where POSIX says EPIPE)."""
    return isinstance(err, BrokenPipeError) or err.errno in (errno.EPIPE, errno.EINVAL)


class OverlayWriter:
    """Stream RGB frames to an H.264 MP4 that browsers play and seek; the file appears only when complete.

    Use as a context manager::

        with OverlayWriter("overlay.mp4", fps=src.fps, width=src.width, height=src.height) as out:
            for index, frame in src:
                out.write(renderer.annotate(frame, items))

    Encoding: libx264, ``yuv420p`` (the only 4:2:0 format every browser
    decodes), ``-movflags +faststart`` (index first, so the HTML report can
    seek before the download ends), constant frame rate ``fps``. Frame ``k``
    of the file is the ``k``-th frame written. ``yuv420p`` needs even width
    and height: an odd frame is padded by repeating its last column and/or
    row, so pixel coordinates are unchanged (``padded_size`` says the size on
    disk). The frames go to ffmpeg's standard input as RGB; the encoder's
    memory settings are at ``_ENCODER_OPTIONS`` in this module.

    The video is encoded to a temporary file beside ``path`` and renamed onto
    it on a clean exit; an exception inside the block, or no frame written,
    kills ffmpeg and removes the temporary file, leaving ``path`` as it was.

    Parameters
    ----------
    path : path-like
        Target ``.mp4``.
    fps : float
        Frame rate of the output (the source's, for a playback in real time).
    width, height : int
        Size of the frames that will be written.
    crf : int
        x264 constant rate factor (0-51, lower is better; 23 is x264's default).
    preset : str
        x264 speed preset. ``ultrafast`` keeps the encoder's memory and CPU small beside the tracker, for a file
        about twice as large as ``veryfast``'s (figures at ``_ENCODER_OPTIONS`` in this module).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        fps: float,
        width: int,
        height: int,
        crf: int = 23,
        preset: str = "ultrafast",
    ) -> None:
        if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
        if int(width) < 1 or int(height) < 1:
            raise ValueError(f"width and height must be >= 1 pixel, got {width}x{height}")
        if not 0 <= crf <= 51:
            raise ValueError(f"crf must lie in 0..51 (x264 quality, lower is better), got {crf}")
        self.path = Path(path)
        self.fps = float(fps)
        self.width, self.height = int(width), int(height)
        self.padded_size = (self.width + self.width % 2, self.height + self.height % 2)
        self.crf, self.preset = int(crf), preset
        self.frames_written = 0
        self._stack: contextlib.ExitStack | None = None
        self._encoder: subprocess.Popen | None = None  # ffmpeg, fed the frames on its stdin
        self._tmp: Path | None = None

    def __enter__(self) -> OverlayWriter:
        if self._stack is not None:
            raise RuntimeError(f"OverlayWriter for {self.path} is already open; use it in one with-block")
        stack = contextlib.ExitStack()
        tmp = stack.enter_context(atomic_path(self.path))
        width, height = self.padded_size
        command = [
            imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error",
            "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
            "-r", str(Fraction(self.fps).limit_denominator()),  # a rational: 30000/1001 stays exact
            "-i", "-", "-an",
            "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", str(self.crf), "-preset", self.preset,
            *_ENCODER_OPTIONS, *_COLOUR_TAGS, "-movflags", "+faststart", str(tmp),
        ]
        try:
            # ffmpeg's messages go to the tool's stderr.
            process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                       env=_encoder_environment(), **_encoder_process_group())
        except BaseException:
            stack.__exit__(*sys.exc_info())  # removes the temporary file; atomic_path suppresses nothing
            raise
        self._stack, self._encoder, self._tmp = stack, process, tmp
        self.frames_written = 0
        return self

    def write(self, frame_rgb: np.ndarray) -> None:
        """Append one ``(height, width, 3) uint8`` RGB frame."""
        if self._encoder is None:
            raise RuntimeError(f"OverlayWriter for {self.path} is not open; use `with OverlayWriter(...) as w:`")
        frame = np.asarray(frame_rgb)
        if frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise ValueError(
                f"frame must be ({self.height}, {self.width}, 3) uint8 RGB like the writer's size, "
                f"got {frame.dtype} {frame.shape}"
            )
        if self.padded_size != (self.width, self.height):
            pad = ((0, self.padded_size[1] - self.height), (0, self.padded_size[0] - self.width), (0, 0))
            frame = np.pad(frame, pad, mode="edge")
        try:
            cast(IO[bytes], self._encoder.stdin).write(np.ascontiguousarray(frame).data)
        except OSError as err:
            if not _pipe_closed(err):
                raise
            raise OSError(f"{self.path}: ffmpeg stopped taking frames after {self.frames_written} (see its messages "
                          f"above); expected it to encode the overlay - check disk space") from None
        self.frames_written += 1

    # Never True: an exception raised in the with-block always propagates, so a type checker may take a `return`
    # inside the block as the end of its function.
    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        stack, encoder, tmp = self._stack, self._encoder, self._tmp
        self._stack = self._encoder = self._tmp = None
        if stack is None:
            return False
        assert encoder is not None and tmp is not None  # set with the stack
        if exc_type is not None:
            try:
                _kill(encoder)
            finally:  # a second Ctrl-C while ffmpeg is reaped still removes the temporary file
                stack.__exit__(exc_type, exc, tb)  # atomic_path suppresses nothing
            return False
        try:
            if self.frames_written == 0:
                raise ValueError(f"{self.path}: no frame was written; an overlay video needs at least one frame")
            try:
                cast(IO[bytes], encoder.stdin).close()
            except OSError as err:
                if not _pipe_closed(err):  # ffmpeg gone: its exit status says why
                    raise
            status = encoder.wait()  # ffmpeg flushes the encoder, then rewrites the file for faststart
            if status != 0 or not tmp.is_file() or tmp.stat().st_size == 0:
                raise OSError(f"{self.path}: ffmpeg failed (exit status {status}, see its messages above); "
                              f"expected it to write an MP4 - check disk space")
        except BaseException:
            try:
                _kill(encoder)
            finally:
                stack.__exit__(*sys.exc_info())  # removes the temporary file; atomic_path suppresses nothing
            raise
        stack.__exit__(None, None, None)  # renames the temporary file onto the target
        return False

    def close(self) -> None:
        """Finish the file (same as leaving the with-block without error)."""
        self.__exit__(None, None, None)


def _kill(encoder: subprocess.Popen) -> None:
    """Stop ffmpeg without letting it finish the file, and reap it."""
    encoder.kill()
    encoder.wait()
    with contextlib.suppress(OSError):
        cast(IO[bytes], encoder.stdin).close()
