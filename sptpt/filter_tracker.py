"""A correlation-filter tracker on its own: the translation and scale filters, following their own boxes.

Why: ``robust``'s runs vote on the box they report (``run_choice="consensus"``),
and a voter is worth most when it errs differently from the others. This
tracker shares nothing with SPTPT but the first box: no superpixels, no
subspaces, no random numbers. Where it agrees with SPTPT runs its box joins
their mean (on Dog1, Car4 and David its size is closer to the truth than
theirs); where it has lost the object (Bolt2, Couple, Jogging) it rarely
lands where a lost SPTPT run did, so it seldom outvotes the runs that kept
it. It costs about a tenth of an SPTPT run. ``TrackerParams.filter_vote``;
measured in ``benchmarks/RESULTS.md`` ("robust development").

DSST (Danelljan et al., BMVC 2014), built from :class:`sptpt.translation.TranslationFilter`
and :class:`sptpt.scale.ScaleFilter`: each frame the translation filter
moves the box to its peak, the scale filter then sizes it there, and both
learn from the new box, every frame (it has no score to reject a frame by).
As in DSST, the box is no wider than the frame's longer side (the scale
filter's bound, :meth:`sptpt.scale.ScaleFilter.init`); on ``../shared/otb``
the bound never binds.
"""

from __future__ import annotations

import numpy as np

from sptpt.affine import box_xywh_from_states, state_from_box_xywh
from sptpt.scale import ScaleFilter
from sptpt.translation import TranslationFilter

__all__ = ["FilterTracker"]


class FilterTracker:
    """DSST from a first box: ``init(rgb, box_xywh)``, then ``update(rgb)`` returns each frame's box.

    Deterministic: the same frames give the same boxes. ``template_size`` is the side of the scale filter's
    samples, px (and the unit of the affine states' scale).
    """

    def __init__(self, template_size: int) -> None:
        self.template_size = template_size
        self._translation = TranslationFilter(template_size)
        self._scale = ScaleFilter(template_size)
        self._state: np.ndarray | None = None

    def init(self, rgb: np.ndarray, box_xywh) -> None:
        """Learn both filters at ``box_xywh`` (0-based ``x, y, w, h``) of the ``(H, W, 3)`` uint8 frame ``rgb``."""
        self._state = state_from_box_xywh(np.asarray(box_xywh, dtype=np.float64), self.template_size)
        self._translation.init(rgb, self._state)
        self._scale.init(rgb, self._state)

    def update(self, rgb: np.ndarray) -> np.ndarray:
        """The box in this frame, ``(4,)`` 0-based ``x, y, w, h``; both filters then learn from it."""
        if self._state is None:
            raise RuntimeError("FilterTracker.update() before init()")
        dx, dy = self._translation.shift(rgb, self._state)
        state = self._state.copy()
        state[0] += dx
        state[1] += dy
        state[2] = self._scale.step(rgb, state, learn=True)
        self._translation.update(rgb, state)
        self._state = state
        return box_xywh_from_states(state[None], self.template_size)[0]
