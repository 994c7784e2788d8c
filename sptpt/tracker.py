"""The Superpixel Tensor Pooling Tracker: ``init(frame, box)`` then ``update(frame)``.

One frame (``docs/design/tracker.md``, "One frame"): draw candidates around the last estimate,
warp each into a 32x32 template, cut it into SNIC superpixels, describe each
superpixel by its midlevel cue histograms, sparse-code those against the
first-frame dictionary, pool the codes into a ``z x s`` tensor per candidate,
and score each tensor by how much better the positive subspace model
reconstructs it than the negative one. The best candidate is the estimate
(``robust``: of the few best near it, the one whose box stands out most from
its surroundings); if it scores above Phi it joins the positive model, and
the negative model is refitted from samples drawn around it. (``robust``
also reports a box sized by a scale filter and centred by a translation
filter beside the run, which leave the run itself untouched; and it tracks
three independent runs, lets a correlation-filter tracker vote with them, and
reports the mean box of those that agree. ``fused`` adds a learned tracker, the
``guide``: each run also draws candidates around its box and ranks candidates
higher the more they overlap it, and it votes too.)
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import os
import threading
from concurrent.futures import Future, wait
from typing import Any, Callable, ContextManager, Protocol

import numba
import numpy as np
from threadpoolctl import OpenBLASController, ThreadpoolController

from sptpt._kernels import InOrder, map_on_threads, on_own_threads
from sptpt._kmeans import KMeansFunction, kmeans_centroids
from sptpt.affine import box_xywh_from_states, state_from_box_xywh, template_labels_to_frame, warp_candidates
from sptpt.boxes import iou_xywh, lies_outside, mean_box
from sptpt.coding import encode_tensors, learn_dictionary
from sptpt.contrast import most_contrasted
from sptpt.features import superpixel_features
from sptpt.filter_tracker import FilterTracker
from sptpt.params import TrackerParams, get_preset
from sptpt.prescreen import AppearanceReference
from sptpt.results import FrameResult, confidence_from_log_likelihood
from sptpt.sampling import draw_candidates, draw_negatives
from sptpt.scale import ScaleFilter
from sptpt.subspace import TensorSubspace, reconstruction_error
from sptpt.superpixels import seed_grid, snic
from sptpt.translation import TranslationFilter

__all__ = ["STAGES", "Guide", "Tracker", "TrackerInspection", "check_params"]

#: The stages a ``stage_timer`` is wrapped around (``prescreen`` only with ``prescreen_share`` < 1, ``shortlist`` only
#: with ``shortlist`` > 0 (the first pass over every candidate, its warp apart), ``scale`` only with
#: ``scale_filter`` or ``reported_scale_filter``, ``translation`` only with ``reported_translation_filter``,
#: ``filter_vote`` only where the correlation-filter tracker votes: ``run_choice="consensus"`` and two runs or more;
#: ``guide`` only with a ``guide``).
STAGES = ("warp", "prescreen", "shortlist", "snic", "features", "coding", "scoring", "positive_update",
          "negative_update", "scale", "translation", "filter_vote", "guide")

StageTimer = Callable[[str], ContextManager]


class Guide(Protocol):
    """A learned tracker that proposes a box each frame (``TrackerParams.guide_particles``, ``guide_vote``).

    It follows the object on its own, from the first box: it never sees SPTPT's boxes, so its boxes depend on the
    frames alone. ``update`` returns its box (0-based ``x, y, w, h``) and its own score of it, higher when surer;
    a box with a non-finite value or no area means it has no box this frame.
    """

    def init(self, rgb: np.ndarray, box_xywh: np.ndarray) -> None: ...

    def update(self, rgb: np.ndarray) -> tuple[np.ndarray, float]: ...


#: A frame's guide box (None where it has none) and the guide's score: what :meth:`Tracker._follow_guide` gives.
Guided = tuple[np.ndarray | None, float]

# The nine one-pixel shifts of the first-frame state that train the dictionary (TPT).
_INIT_SHIFTS = np.array([(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)], dtype=np.float64)


def _no_timer(stage: str) -> ContextManager:
    return contextlib.nullcontext()


# Median absolute deviation to standard deviation for normally distributed values.
_MAD_TO_STD = 1.4826


class _BlasOnOneThread:
    """BLAS limited to one thread while anyone holds this: its matrices here are small, and its threads only fight
    numba's.

    Counted, because the limit is the whole process's: frames tracked ahead (:meth:`Tracker.submit`) hold it until
    their runs are done, and a second tracker must not lift it while the first one's runs still work. The last
    holder may let go on another thread than the first took it: threadpoolctl lets only one thread (the first to
    set a limit) change OpenBLAS's pthreads pool and silently ignores the others, so control is handed to
    whichever thread sets or lifts the limit here, under this lock.
    The controller scans the loaded libraries once (about 5 ms); each limit after that is cheap.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._holders = 0
        self._controller: ThreadpoolController | None = None
        self._limiter: Any | None = None  # threadpoolctl's limit while held (threadpoolctl has no types)

    def acquire(self) -> None:
        with self._lock:
            if self._holders == 0:
                if self._controller is None:
                    self._controller = ThreadpoolController()
                _hand_over_openblas()
                self._limiter = self._controller.limit(limits=1, user_api="blas")
                _hand_over_openblas()
            self._holders += 1

    def release(self) -> None:
        with self._lock:
            self._holders -= 1
            if self._holders == 0:
                assert self._limiter is not None  # the acquire that made the holders one set it
                _hand_over_openblas()
                self._limiter.restore_original_limits()
                self._limiter = None
                _hand_over_openblas()

    @contextlib.contextmanager
    def held(self):
        self.acquire()
        try:
            yield
        finally:
            self.release()

    def forget(self) -> None:
        """In a forked child: the parent's holders are not there to let go, so the limit is lifted now and the
        child's own holders start from none."""
        self._lock = threading.Lock()
        limiter, self._holders, self._limiter = self._limiter, 0, None
        if limiter is not None:
            _hand_over_openblas()
            limiter.restore_original_limits()
            _hand_over_openblas()


def _hand_over_openblas() -> None:
    """Let the next thread that sets an OpenBLAS limit through threadpoolctl take control (see
    :class:`_BlasOnOneThread`); a no-op with threadpoolctl before 3.5, which had no controlling thread."""
    clear = getattr(OpenBLASController, "clear_controlling_thread", None)
    if clear is not None:
        clear(force=True)


_BLAS_ON_ONE_THREAD = _BlasOnOneThread()
os.register_at_fork(after_in_child=_BLAS_ON_ONE_THREAD.forget)


def _single_threaded_blas() -> ContextManager:
    """BLAS on one thread inside the block (see :class:`_BlasOnOneThread`)."""
    return _BLAS_ON_ONE_THREAD.held()


@dataclasses.dataclass(frozen=True)
class TrackerInspection:
    """What each run of a tracker holds now, and how its current models score given boxes of a frame.

    Returned by :meth:`Tracker.inspect`, for diagnosis: for ``R`` runs (``TrackerParams.independent_runs``) and
    ``N`` boxes, each ``(R, ...)`` array holds one row per run, in run order.

    Attributes
    ----------
    estimate_xywh : (R, 4) float64 ndarray
        Each run's current estimate, 0-based ``x, y, w, h``: the box of its state, around which it searches the
        next frame (after ``redetect_after`` missed frames also around its last accepted state). With
        ``scale_filter`` its size is the filter's; ``reported_scale_filter`` and the translation filter move only
        the box a frame reports, not this one.
    subspace : (R,) bool ndarray
        Whether the run scores with its subspace models (both exist), as ``FrameResult.scoring == "subspace"``;
        else with the bootstrap intersection.
    positive_updates : (R,) int64 ndarray
        How many times the run has fitted or updated its positive model: once per ``update_every`` accepted frames
        (the first-frame tensor counts toward the first batch).
    positive_ranks, negative_ranks : (R, 3) int64 ndarray
        Codeword, superpixel and sample-mode ranks of the models the run scores with (under
        ``negative_rank_matched``, the negative model truncated to the positive's ranks); 0 where the model does not
        exist yet.
    positive_error_modes, negative_error_modes : (R, N) float64 ndarray
        Squared reconstruction error of each box's code tensor in modes 1-2 under the positive and the negative
        model (:meth:`sptpt.subspace.TensorSubspace.errors`); NaN where the model does not exist yet.
    positive_error_sample, negative_error_sample : (R, N) float64 ndarray
        The same in the sample mode.
    positive_error, negative_error : (R, N) float64 ndarray
        ``RE+`` and ``RE-``: the two combined as ``TrackerParams.re_mode`` says
        (:func:`sptpt.subspace.reconstruction_error`, paper eqs. 5-7); NaN where the model does not exist yet.
    log_likelihood : (R, N) float64 ndarray
        The score the run would give each box now, as ``FrameResult.particle_scores``: ``RE- - RE+`` (paper eq. 11)
        where ``subspace``, else the bootstrap intersection with the first frame's code tensor. Equal to the
        tracker's own score of the same box up to rounding (the tracker scores a box among the other candidates).
    """

    estimate_xywh: np.ndarray
    subspace: np.ndarray
    positive_updates: np.ndarray
    positive_ranks: np.ndarray
    negative_ranks: np.ndarray
    positive_error_modes: np.ndarray
    positive_error_sample: np.ndarray
    negative_error_modes: np.ndarray
    negative_error_sample: np.ndarray
    positive_error: np.ndarray
    negative_error: np.ndarray
    log_likelihood: np.ndarray

    def __post_init__(self) -> None:
        runs, n_boxes = len(self.estimate_xywh), np.shape(self.log_likelihood)[-1]
        per_run = {"estimate_xywh": (runs, 4), "subspace": (runs,), "positive_updates": (runs,),
                   "positive_ranks": (runs, 3), "negative_ranks": (runs, 3)}
        for field in dataclasses.fields(self):
            value = np.asarray(getattr(self, field.name))
            expected = per_run.get(field.name, (runs, n_boxes))  # the rest: one value per run and box
            if value.shape != expected:
                raise ValueError(f"{field.name} must have shape {expected} for {runs} runs and {n_boxes} boxes, "
                                 f"got {value.shape}")
            object.__setattr__(self, field.name, value)


class Tracker:
    """SPTPT, with got10k's tracker contract.

    With ``params.independent_runs`` R > 1 the tracker follows the object with R independent runs and reports,
    each frame, what ``params.run_choice`` picks (the more confident run, the one whose box stands out most from
    its surroundings, or the mean box of the runs that agree, with ``filter_vote`` of a correlation-filter
    tracker's box too); every run's box is in ``FrameResult.run_boxes_xywh``.

    Parameters
    ----------
    params : TrackerParams, optional
        Defaults to the ``paper`` preset.
    seed : int or numpy.random.Generator, optional
        Seeds every random choice (dictionary, candidates, negatives): the same
        seed and frames give bit-identical results.
    stage_timer : callable, optional
        ``stage_timer(name)`` returns a context manager wrapped around each
        stage of :data:`STAGES`; benchmarks use it to time stages without the
        tracker measuring anything itself. With several runs it is entered
        from their threads at the same time, so what it records must be
        thread-safe; the stages of the runs then overlap in time.
    guide : Guide, optional
        A learned tracker beside SPTPT, needed by (and only by) parameters that use one
        (``guide_particles``, ``guide_prior``, ``guide_vote``: the ``fused`` preset). It is given the first frame
        and box, then each frame before the runs; its box is where each run draws more candidates and which
        candidates it favours, and, with ``guide_vote``, one more vote. ``FrameResult.guide_box_xywh`` reports it.
    kmeans : callable, optional
        What runs the k-means of each run's dictionary on the first frame: ``kmeans(features, n_clusters, n_init,
        seed)`` returns the centroids, and must equal the default (scikit-learn's, in this process) to the bit.
        The tool passes one that runs the same function in a child process, to keep scikit-learn's memory out of
        the tracking process.

    Examples
    --------
    >>> import numpy as np
    >>> from sptpt import Tracker, preset
    >>> rng = np.random.default_rng(0)
    >>> frame = rng.integers(0, 60, (120, 160, 3), dtype=np.uint8)
    >>> frame[40:70, 50:90] = (200, 40, 40)                 # a red object
    >>> tracker = Tracker(preset("fast"), seed=0)
    >>> first = tracker.init(frame, (50, 40, 40, 30))      # (H, W, 3) uint8 RGB; box x, y, w, h, 0-based
    >>> moved = np.roll(frame, 3, axis=1)                   # the object 3 px to the right
    >>> result = tracker.update(moved)
    >>> bool(abs(result.box_xywh[0] - 53) < 3), result.box_xywh.shape
    (True, (4,))
    """

    def __init__(
        self,
        params: TrackerParams | None = None,
        *,
        seed: int | np.random.Generator | None = None,
        stage_timer: StageTimer | None = None,
        guide: Guide | None = None,
        kmeans: KMeansFunction = kmeans_centroids,
    ) -> None:
        self.params = get_preset("paper") if params is None else params
        if not isinstance(self.params, TrackerParams):
            raise TypeError(f"params must be a TrackerParams, got {type(self.params).__name__}")
        if self.params.uses_guide != (guide is not None):
            raise ValueError("guide_particles, guide_prior and guide_vote need a guide (Tracker(params, guide=...)), "
                             "and a guide needs one of them: " + ("pass a guide" if guide is None
                                                                  else "set one, or drop the guide"))
        self._guide = guide
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        p, timer = self.params, stage_timer or _no_timer
        if p.independent_runs == 1:
            # One run draws from the tracker's own stream, so a one-run preset's boxes depend on nothing else.
            self._runs = [_Run(p, rng, timer, kmeans)]
        else:
            # Each run gets a random stream of its own, seeded from the tracker's; whether a frame is easy is the
            # tracker's call (``easy_after``), passed to each run's update as its share of the candidates.
            single = dataclasses.replace(p, independent_runs=1, easy_after=0)
            child_seeds = rng.integers(0, 2**63 - 1, size=p.independent_runs)
            self._runs = [_Run(single, np.random.default_rng(int(s)), timer, kmeans) for s in child_seeds]
        # Draws no random numbers, so the runs are the same with it and without it.
        voting = p.filter_vote and voting_allowed(p)
        self._filter_voter = FilterTracker(p.template_size) if voting else None
        self._time = timer
        self._agreed = 0  # frames in a row on which the runs agreed (``easy_after``)
        # Frames submitted and not yet collected, oldest first: a FrameResult, or an _InFlight still being tracked.
        self._submitted: collections.deque = collections.deque()
        # Each run's frames, and the voter's, one after another on a thread of their own (only once submitted).
        self._lanes = [InOrder() for _ in range(len(self._runs) + (self._filter_voter is not None))]
        self._guide_votes = p.guide_vote and voting_allowed(p)

    @property
    def guide(self) -> Guide | None:
        """The learned tracker beside SPTPT (``guide=``), or None."""
        return self._guide

    def init(self, frame: np.ndarray, box_xywh) -> FrameResult:
        """Start tracking the object in ``box_xywh`` of ``frame``.

        Parameters
        ----------
        frame : (H, W, 3) or (H, W) uint8 ndarray
            RGB or grayscale frame.
        box_xywh : sequence of 4 numbers
            0-based ``x, y, w, h`` of the object; must have positive size and
            overlap the frame.

        Returns
        -------
        FrameResult
            The given box, with confidence 1 and ``scoring='init'``.
        """
        self._refuse_if_submitted("init")
        with _single_threaded_blas():
            results = [run.init(frame, box_xywh) for run in self._runs]
        self._agreed = 0
        if self._filter_voter is not None:  # after the runs, which have checked the frame and the box
            with self._time("filter_vote"):
                self._filter_voter.init(_as_rgb(frame), results[0].box_xywh)
        if self._guide is not None:
            with self._time("guide"):
                self._guide.init(_as_rgb(frame), results[0].box_xywh)
            return dataclasses.replace(_reported(results, 0), guide_box_xywh=results[0].box_xywh, guide_score=1.0)
        return _reported(results, 0)

    def update(self, frame: np.ndarray, *, details: bool = False) -> FrameResult:
        """Track the object into the next frame.

        Parameters
        ----------
        frame : (H, W, 3) or (H, W) uint8 ndarray
            Same size as the first frame.
        details : bool
            Also return the particles with their scores and the winning
            candidate's superpixels mapped to the frame (for overlays).

        Returns
        -------
        FrameResult
        """
        self._refuse_if_submitted("update")
        return self._track_now(frame, details)

    def _track_now(self, frame: np.ndarray, details: bool) -> FrameResult:
        with _single_threaded_blas():
            if len(self._runs) == 1 and self._guide is None:
                return self._runs[0].update(frame, details=details)  # the run checks the frame itself
            # Checked before any run or the voter moves on: a frame they would refuse leaves them all as they were.
            rgb = self._runs[0].sequence_rgb(frame, "update")
            guided = self._follow_guide(rgb)
            share = self.params.easy_share if 0 < self.params.easy_after <= self._agreed else 1.0
            results, voter_box = self._update_runs(rgb, details, share, guided)
        return self._report(rgb, results, voter_box, guided)

    def submit(self, frame: np.ndarray, *, details: bool = False) -> None:
        """Start tracking the next frame and return without waiting for it; :meth:`collect` gives its result.

        The same results as :meth:`update`, in the same order, to the bit; but each run (and the voter) goes on to
        the frames submitted after this one as soon as it has finished its own part of this one, instead of
        waiting for the slowest run every frame: no run needs another's result to track its next frame. Keeps
        both cores busy where :meth:`update` leaves one idle while the last run of a frame finishes. Submit a few
        frames ahead of the one collected (two, in the annotator).

        Several trackers fed this way (one per target) have all their runs working at once: the operating system
        shares the cores among them, as among one tracker's runs.

        Where runs cannot go ahead (one run; one kernel thread, as in a batch worker with one core; more runs
        than one more than the kernel threads; or ``easy_after``, whose next share waits on this frame's
        consensus), the frame is tracked here, at once, as :meth:`update` would.

        ``frame`` is read until its result is collected: do not write into it before. Checked here, as by
        :meth:`update`: a frame that would be refused raises before any run moves on. Where the frame is tracked
        at once, an error of a frame submitted before it (or of this one) is raised here rather than by
        :meth:`collect`.
        """
        if not (self.params.easy_after == 0 and _all_at_once(numba.get_num_threads(), len(self._runs))):
            self._settle_submitted()  # every run has finished the frames before this one
            self._submitted.append(self._track_now(frame, details))
            return
        rgb = self._runs[0].sequence_rgb(frame, "update")
        guided = self._follow_guide(rgb)  # here, in frame order: every run's task of this frame needs its box
        tasks = self._tasks(rgb, details, 1.0, guided)
        # Held until the frame's last task ends, not until it is collected: a tracker dropped with frames in
        # flight must not leave the process's BLAS on one thread.
        _BLAS_ON_ONE_THREAD.acquire()
        release = _CountDown(len(tasks), _BLAS_ON_ONE_THREAD.release)
        futures: list[Future] = []
        try:
            for lane, task in zip(self._lanes, tasks):
                futures.append(lane.submit(functools.partial(_on_one_kernel_thread, task)))
                futures[-1].add_done_callback(release)
        finally:
            for _ in range(len(tasks) - len(futures)):  # interrupted part-way: those never submitted let go now
                release()
            if futures:  # recorded even then, so that collect or discard waits for what did start
                self._submitted.append(_InFlight(rgb, futures, guided, complete=len(futures) == len(tasks)))

    def collect(self) -> FrameResult:
        """The result of the oldest frame submitted and not yet collected, once it is tracked.

        Raises
        ------
        RuntimeError
            When nothing is submitted.
        Exception
            What a run raised while tracking the frame. The frames submitted after it are then dropped (what
            their runs had not started is cancelled, what they had is waited for), so each run is left part-way:
            start again with :meth:`init`.
        """
        if not self._submitted:
            raise RuntimeError("collect() with no frame submitted: submit(frame) first")
        self._settle(0)
        return self._submitted.popleft()

    @property
    def submitted(self) -> int:
        """Frames submitted and not yet collected."""
        return len(self._submitted)

    def discard(self) -> None:
        """Drop every frame submitted and not yet collected (an interrupted loop): what the runs had not started
        is cancelled, what they had is waited for. The runs are then part-way: start again with :meth:`init` to
        track on."""
        self._drop_from(0)

    def __getstate__(self) -> dict:
        # A copy (copy.deepcopy, pickle) starts with nothing submitted and lanes of its own.
        self._refuse_if_submitted("copying")
        return self.__dict__.copy()

    def _drop_from(self, index: int) -> None:
        """Drop the submitted entries from ``index`` on, once their runs have stopped."""
        dropped = [self._submitted.pop() for _ in range(len(self._submitted) - index)]
        futures = [future for entry in dropped if isinstance(entry, _InFlight) for future in entry.futures]
        for future in futures:
            future.cancel()  # a call not started yet never starts (its done-callbacks still run)
        wait(futures)

    def _tasks(self, rgb: np.ndarray, details: bool, share: float,
               guided: Guided | None) -> list[Callable[[], object]]:
        """Each run's update of the frame and, with the voter, its vote (last)."""
        # Only with a guide does a run hear of it.
        extra = {} if guided is None else {"guide_box": guided[0]}
        tasks: list[Callable[[], object]] = [functools.partial(run.update, rgb, details=details, share=share, **extra)
                                             for run in self._runs]
        if self._filter_voter is not None:
            tasks.append(functools.partial(self._vote, rgb))
        return tasks

    def _refuse_if_submitted(self, method: str) -> None:
        if self._submitted:
            raise RuntimeError(f"{method}() with {len(self._submitted)} submitted frame(s) not collected: "
                               f"collect() them first, or discard() them")

    def _follow_guide(self, rgb: np.ndarray) -> Guided | None:
        """The guide's box and score for this frame (the box None where it has none); None without a guide."""
        if self._guide is None:
            return None
        with self._time("guide"):
            box, score = self._guide.update(rgb)
        box = np.asarray(box, dtype=np.float64).reshape(4)
        found = bool(np.isfinite(box).all() and box[2] > 0 and box[3] > 0)
        return (box if found else None), float(score)

    def _vote(self, rgb: np.ndarray) -> np.ndarray:
        assert self._filter_voter is not None  # only trackers with a voter vote
        with self._time("filter_vote"):
            return self._filter_voter.update(rgb)

    def _settle_submitted(self) -> None:
        for index in range(len(self._submitted)):
            self._settle(index)

    def _settle(self, index: int) -> None:
        """Turn submitted entry ``index`` (those before it settled) into its FrameResult, waiting for its runs."""
        entry = self._submitted[index]
        if not isinstance(entry, _InFlight):
            return
        wait(entry.futures)
        failed = next((f.exception() for f in entry.futures if f.exception() is not None), None)
        if failed is None and not entry.complete:
            failed = RuntimeError("submit() was interrupted before every run had this frame: start again with "
                                  "init()")
        if failed is not None:
            self._drop_from(index)
            raise failed
        done = [future.result() for future in entry.futures]
        runs = len(self._runs)
        self._submitted[index] = self._report(entry.rgb, done[:runs], done[runs] if len(done) > runs else None,
                                              entry.guided)

    def _report(self, rgb: np.ndarray, results: list[FrameResult], voter_box: np.ndarray | None,
                guided: Guided | None = None) -> FrameResult:
        """The frame's reported result from every run's (and the voters' boxes): what ``run_choice`` picks."""
        p = self.params
        chosen = _more_confident(results)
        if p.run_choice == "contrast":
            chosen = _most_contrasted(results, rgb, chosen)
        if p.run_choice == "consensus" and len(results) > 1:
            voters = [] if voter_box is None else [voter_box]
            if self._guide_votes and guided is not None and guided[0] is not None:
                voters.append(guided[0])
            boxes = np.stack([r.box_xywh for r in results] + voters)
            chosen, agreeing = _consensus(boxes, len(results), rgb, chosen)
            reported = dataclasses.replace(_reported(results, chosen), box_xywh=mean_box(boxes[sorted(agreeing)]))
        else:
            reported = _reported(results, chosen)
        if p.easy_after > 0:
            self._agreed = self._agreed + 1 if _runs_agree(reported, results) else 0
        if guided is not None:
            no_box = np.full(4, np.nan)
            reported = dataclasses.replace(reported, guide_box_xywh=no_box if guided[0] is None else guided[0],
                                           guide_score=guided[1])
        return reported

    def inspect(self, frame: np.ndarray, boxes_xywh=None) -> TrackerInspection:
        """How each run's current models score ``boxes_xywh`` in ``frame``, with its estimate, ranks and updates.

        For diagnosis (``benchmarks/diagnose_sptpt.py``): call it after :meth:`init` or :meth:`update`, typically
        with the frame just tracked, to see how the models as they are now score the estimate, the true box or any
        other box. It only reads: it draws no random numbers and changes no run, so the boxes of later frames are
        the same as without it; nor does it enter the ``stage_timer``.

        Parameters
        ----------
        frame : (H, W, 3) or (H, W) uint8 ndarray
            RGB or grayscale frame of the sequence's size.
        boxes_xywh : (N, 4) or (4,) array_like of float, optional
            0-based ``x, y, w, h`` with positive width and height, each scored as the axis-aligned candidate of
            that box (:func:`sptpt.affine.state_from_box_xywh`). None (the default): no box, N = 0; the estimates,
            ranks and update counts are still there, and cost no warping or coding.

        Returns
        -------
        TrackerInspection

        Raises
        ------
        RuntimeError
            Before :meth:`init`.
        ValueError, TypeError
            On a frame of another size or type, or boxes that are not ``(N, 4)`` finite numbers with positive size.
        """
        self._refuse_if_submitted("inspect")
        boxes = np.empty((0, 4)) if boxes_xywh is None else _validate_boxes(boxes_xywh)
        with _single_threaded_blas():
            rows = [run.inspect(frame, boxes) for run in self._runs]
        return TrackerInspection(**{name: np.stack([row[name] for row in rows]) for name in rows[0]})

    def _update_runs(self, rgb: np.ndarray, details: bool, share: float = 1.0,
                     guided: Guided | None = None
                     ) -> tuple[list[FrameResult], np.ndarray | None]:
        """Every run's update with ``share`` of its candidates, and the voter's box (None without a voter); with
        more than one kernel thread, side by side, one kernel thread each.

        A run's kernels keep both cores busy, but between them it scores, refits and chooses on one; side by
        side, one run's serial work overlaps another's kernels. Up to one run more than the threads (three on two
        cores) all run at once, and the voter beside them, and the operating system shares the cores among them:
        measured, the runs at once were 6.6% faster than the third run after the other two with every thread,
        whose serial work left a core idle (RESULTS.md, "The default's speed"); the voter beside them rather
        than after them gained 0-3%, within noise (HISTORY.md). With still more runs, the largest multiple of the
        thread count runs side by side and the rest after them on every thread, so the threads never exceed the
        kernel threads (a batch worker's share of the cores) by more than one; the voter then follows them. Runs
        and the voter share nothing, so their results are the same as one after the other. (:meth:`submit` lets
        the runs that go all at once go on to later frames too.)
        """
        threads, runs = numba.get_num_threads(), len(self._runs)
        tasks = self._tasks(rgb, details, share, guided)
        if _all_at_once(threads, runs):
            done = on_own_threads(_on_one_kernel_thread, tasks)
        elif threads > 1 and runs > 1:
            side_by_side = runs - runs % threads
            done = map_on_threads(_on_one_kernel_thread, tasks[:side_by_side], threads)
            done += [task() for task in tasks[side_by_side:]]  # the voter last
        else:
            done = [task() for task in tasks]
        return done[:runs], done[runs] if len(done) > runs else None


def check_params(params: TrackerParams) -> None:
    """Raise the ValueError a :class:`Tracker` would raise for ``params``, without building one.

    The checks that need the tracker's code (a superpixel rank above the superpixels a template gets), beyond
    those ``TrackerParams`` makes itself. A tool validates a configuration with it before any frame is read.

    Parameters
    ----------
    params : TrackerParams
        The parameters to check.

    Raises
    ------
    ValueError
        A combination the tracker cannot run, and how to mend it.

    Examples
    --------
    >>> import dataclasses
    >>> from sptpt import check_params, preset
    >>> check_params(preset("robust"))
    >>> check_params(dataclasses.replace(preset("paper"), ranks=(10, 500, 6)))
    Traceback (most recent call last):
    ...
    ValueError: parameter ranks=(10, 500, 6) is invalid: the superpixel rank 500 exceeds ...
    """
    superpixels = _superpixels_per_template(params)
    if params.ranks[1] > superpixels:
        raise ValueError(f"parameter ranks={params.ranks!r} is invalid: the superpixel rank {params.ranks[1]} exceeds "
                         f"the {superpixels} superpixels per template; lower it")


def _superpixels_per_template(p: TrackerParams) -> int:
    return seed_grid(p.template_size, p.template_size, p.n_superpixels, seeding=p.seeding).shape[0]


def voting_allowed(p: TrackerParams) -> bool:
    """Whether boxes other than the runs' can vote (``filter_vote``, ``guide_vote``): a consensus of two runs or
    more."""
    return p.run_choice == "consensus" and p.independent_runs > 1


def _all_at_once(threads: int, runs: int) -> bool:
    """Whether ``runs`` runs (and the voter) go all at once, one kernel thread each, with ``threads`` kernel
    threads (:meth:`Tracker._update_runs`); only then can a run go ahead of the others (:meth:`Tracker.submit`)."""
    return threads > 1 and 1 < runs <= threads + 1


@dataclasses.dataclass(frozen=True)
class _InFlight:
    """A submitted frame while its runs track it: the frame, and each run's future (the voter's last)."""

    rgb: np.ndarray
    futures: list[Future]
    guided: Guided | None  # the guide's box and score (Tracker._follow_guide)
    complete: bool = True  # False: submit was interrupted before every run had the frame


class _CountDown:
    """Calls ``then()`` on the ``count``-th call of itself (from any thread)."""

    def __init__(self, count: int, then: Callable[[], object]) -> None:
        self._left, self._then, self._lock = count, then, threading.Lock()

    def __call__(self, *ignored) -> None:
        with self._lock:
            self._left -= 1
            last = self._left == 0
        if last:
            self._then()


#: A run's box that overlaps the reported box at least this much agrees closely enough for an easy frame
#: (``easy_after``): the flags' ``run_iou`` at 0.8, as screened on stored runs (HISTORY.md, 2026-11-28).
_EASY_IOU = 0.8


def _runs_agree(reported: FrameResult, results: list[FrameResult]) -> bool:
    """Whether every run accepted its estimate and every run's box overlaps the reported box at least
    :data:`_EASY_IOU`."""
    boxes = np.stack([r.box_xywh for r in results])
    return (all(r.accepted for r in results)
            and bool(np.nan_to_num(iou_xywh(boxes, reported.box_xywh), nan=0.0).min() >= _EASY_IOU))


def _on_one_kernel_thread(call: Callable[[], object]) -> object:
    """``call()`` with one kernel thread (numba's count is per thread; the caller's is restored after it)."""
    own = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return call()
    finally:
        numba.set_num_threads(own)


class _Run:
    """One SPTPT run: its random stream, dictionary, candidates, models and state."""

    def __init__(self, params: TrackerParams, rng: np.random.Generator, time: StageTimer,
                 kmeans: KMeansFunction) -> None:
        self.params = p = params
        self._rng = rng
        self._time = time
        self._kmeans = kmeans
        check_params(p)
        self.n_superpixels = _superpixels_per_template(p)
        self._sigma = np.asarray(p.motion_sigma, dtype=np.float64)
        self._frame_shape: tuple[int, int] | None = None

    def init(self, frame: np.ndarray, box_xywh) -> FrameResult:
        rgb = _as_rgb(frame)
        box = _validate_box(box_xywh, rgb.shape[:2])
        p = self.params
        self._frame_shape = rgb.shape[:2]
        self._state = state_from_box_xywh(box, p.template_size)
        shifted = np.repeat(self._state[None], len(_INIT_SHIFTS), axis=0)
        shifted[:, :2] += _INIT_SHIFTS
        features, labels = self._features(rgb, shifted)
        self._dictionary = learn_dictionary(
            features.reshape(-1, features.shape[-1]), p.n_atoms, rng=self._rng, n_init=p.kmeans_restarts,
            kmeans=self._kmeans,
        )
        unshifted = int(np.flatnonzero((_INIT_SHIFTS == 0).all(axis=1))[0])
        self._first_codes = self._code(features[unshifted : unshifted + 1])[0]
        # The superpixels of the estimate's template and its codes: a shortlist's first pass cuts every candidate
        # into them, and starts each superpixel's coding from the atoms of the estimate's.
        self._estimate = (labels[unshifted].copy(), self._first_codes)
        self._first_mass = float(self._first_codes.sum())
        self._buffer: list[np.ndarray] = [self._first_codes]
        self._positive: TensorSubspace | None = None
        self._negative: TensorSubspace | None = None
        self._frame_number = 1
        self._accepted_count = 0
        self._positive_updates = 0  # fits and updates of the positive model (Tracker.inspect reports it)
        # Running level and re-detection (off in the paper preset): winning log-likelihoods of accepted
        # subspace-scored frames, consecutive misses, and the last accepted state to search around.
        self._levels: list[float] = []
        self._misses = 0
        self._anchor = self._state.copy()
        self._scale_filter: ScaleFilter | None = None
        if p.scale_filter or p.reported_scale_filter:
            with self._time("scale"):
                self._scale_filter = ScaleFilter(p.template_size)
                self._scale_filter.init(rgb, self._state)
        # The reported box's scale under ``reported_scale_filter``: the filter's own, apart from the state's, and
        # within the filter's bounds (``ScaleFilter.init``).
        self._reported_scale = float(self._state[2])
        # The prescreen's look of the object (None: every candidate is evaluated in full).
        self._reference: AppearanceReference | None = None
        if p.prescreen_share < 1:
            with self._time("prescreen"):
                self._reference = AppearanceReference(warp_candidates(rgb, self._state[None], p.template_size)[0])
        self._translation_filter: TranslationFilter | None = None
        if p.reported_translation_filter:
            with self._time("translation"):
                self._translation_filter = TranslationFilter(p.template_size)
                self._translation_filter.init(rgb, self._state)
        return FrameResult(
            box_xywh=box, log_likelihood=self._first_mass, confidence=1.0, accepted=True, scoring="init"
        )

    def update(self, frame: np.ndarray, *, details: bool, share: float = 1.0,
               guide_box: np.ndarray | None = None) -> FrameResult:
        """Track one frame drawing ``share`` of each round's candidates and of the shortlist (an easy frame: the
        tracker's ``easy_after``). The re-detection round keeps its own counts: it follows missed frames, which
        an easy frame never does. ``guide_box``: the guide's box this frame, around which ``guide_particles``
        more candidates are drawn (None: no guide, or it has no box)."""
        rgb = self.sequence_rgb(frame, "update")
        p = self.params
        self._frame_number += 1
        sigma = self._motion_sigma(self._state)
        shortlist = _shared(p.shortlist, share)
        states, codes, labels, scores, scoring = self._round(rgb, self._state, _shared(p.n_particles, share), sigma,
                                                             self._estimate, shortlist)
        rounds = [(states, codes, labels, scores)]
        if p.refine_particles > 0:
            # Second, narrower round around the first round's winner: most of the
            # accuracy of many particles for a fraction of the templates (fast preset).
            seed = int(np.argmax(scores))
            rounds.append(self._round(rgb, states[seed], _shared(p.refine_particles, share),
                                      sigma * p.refine_sigma_scale, (labels[seed], codes[seed]), shortlist)[:4])
        level = self._level() if scoring == "subspace" and p.level_window > 0 else None
        if level is not None and p.redetect_after > 0 and self._misses >= p.redetect_after:
            # The target has been missing for a while: also search wide around where it was last accepted.
            rounds.append(self._round(rgb, self._anchor, p.redetect_particles, self._redetect_sigma(self._anchor),
                                      self._estimate, p.shortlist)[:4])
        if guide_box is not None and p.guide_particles > 0:
            rounds.append(self._guide_round(rgb, guide_box, sigma, shortlist))
        if len(rounds) > 1:
            states, codes, labels, scores = (np.concatenate(parts) for parts in zip(*rounds))
        ranked = scores
        if guide_box is not None and p.guide_prior > 0 and level is not None:
            # The guide's box as an observation: candidates are ranked by their score plus a bonus growing with
            # their overlap of it, in units of the run's usual spread of scores; the score itself (reported, and
            # judged for learning) stays the model's.
            overlap = np.nan_to_num(iou_xywh(box_xywh_from_states(states, p.template_size), guide_box), nan=0.0)
            ranked = scores + p.guide_prior * level[1] * overlap
        best = int(np.argmax(ranked))
        if p.contrast_candidates > 1:
            with self._time("scoring"):  # choosing among the candidates is part of scoring them
                best = _most_contrasted_candidate(rgb, states, ranked, best, p.contrast_candidates,
                                                  p.template_size)
        self._state = states[best].copy()
        self._estimate = (labels[best].copy(), codes[best].copy())  # not views that keep the round's arrays
        if p.scale_filter:
            # The candidates chose the centre; the scale filter sets the size there. The winner's codes (which the
            # models learn from below), its log-likelihood and its acceptance (which are reported) stay those of
            # its own template, up to 1.02**16 = 1.37x larger or smaller than the returned box: the switch was
            # measured this way (HISTORY.md, "robust development").
            assert self._scale_filter is not None  # init makes it under either scale filter
            with self._time("scale"):
                self._state[2] = max(self._state[2] * self._scale_filter.factor(rgb, self._state),
                                     1.0 / p.template_size)
        log_likelihood = float(scores[best])
        accepted = bool(log_likelihood > p.accept_threshold)
        if scoring == "subspace" and p.level_window > 0:
            if level is None or len(self._levels) < p.level_min_count:
                # No settled level yet: accept, as the paper accepts its bootstrap frames.
                accepted = True
            else:
                median, spread = level
                accepted = accepted or log_likelihood >= median - p.accept_drop * spread
            self._misses = 0 if accepted else self._misses + 1
        sized_state = self._state
        if p.reported_scale_filter:
            # SPTPT's state keeps its own scale, so its search and models are the filter-free run's; the box
            # reported takes the filter's scale at the state's centre.
            sized_state = self._state.copy()
            sized_state[2] = self._reported_scale
            assert self._scale_filter is not None  # init makes it under either scale filter
            with self._time("scale"):
                # On accepted frames the filter then learns at the new scale, from the state's centre.
                self._reported_scale = self._scale_filter.step(rgb, sized_state, learn=accepted)
            sized_state[2] = self._reported_scale
        reported_state = sized_state
        if self._translation_filter is not None:
            # Only the reported centre moves; on accepted frames the filter learns from SPTPT's centre, not this one.
            with self._time("translation"):
                dx, dy = self._translation_filter.shift(rgb, sized_state, learn=accepted)
            reported_state = sized_state.copy()
            reported_state[0] += dx
            reported_state[1] += dy
        if accepted:
            self._anchor = self._state.copy()
            if p.scale_filter:  # the search's scale filter learns at the state it sized (the reported box's
                # filters learnt in step and shift above; the parameters forbid both scale filters at once)
                assert self._scale_filter is not None  # init makes it under either scale filter
                with self._time("scale"):
                    self._scale_filter.update(rgb, self._state)
            if scoring == "subspace" and p.level_window > 0:
                self._levels.append(log_likelihood)
                del self._levels[: -p.level_window]
            self._learn(rgb, codes[best])
            if self._reference is not None:
                with self._time("prescreen"):
                    self._reference.learn(warp_candidates(rgb, self._state[None], p.template_size)[0])
        if scoring == "subspace":
            confidence = confidence_from_log_likelihood(log_likelihood, scale=p.confidence_scale)
        else:
            # The intersection with the first-frame codes, as a share of their mass.
            confidence = float(np.clip(log_likelihood / self._first_mass, 0.0, 1.0)) if self._first_mass > 0 else 0.0
        extra = {}
        if details:
            # The labels are the winner's template's, so they are placed with the winner's state (before any
            # scale filter step or translation filter shift of the reported box).
            assert self._frame_shape is not None  # set by init, before any update
            frame_labels, origin = template_labels_to_frame(labels[best], states[best], self._frame_shape)
            extra = dict(
                particles_xywh=box_xywh_from_states(states, p.template_size),
                particle_scores=scores,
                superpixel_labels=frame_labels,
                superpixel_origin_xy=origin,
            )
        return FrameResult(
            box_xywh=box_xywh_from_states(reported_state, p.template_size),
            log_likelihood=log_likelihood,
            confidence=confidence,
            accepted=accepted,
            scoring=scoring,
            **extra,
        )

    def inspect(self, frame: np.ndarray, boxes_xywh: np.ndarray) -> dict[str, np.ndarray | np.generic]:
        """One run's row of :class:`TrackerInspection` for ``(N, 4)`` checked boxes; reads, never writes."""
        rgb = self.sequence_rgb(frame, "inspect")
        p = self.params
        states = np.array([state_from_box_xywh(box, p.template_size) for box in boxes_xywh]).reshape(-1, 6)
        codes = self._codes(rgb, states, time=_no_timer)[0] if len(states) else None
        positive, negative = self._scoring_models()
        row: dict[str, np.ndarray | np.generic] = {
            "estimate_xywh": box_xywh_from_states(self._state, p.template_size),
            "subspace": np.bool_(positive is not None and negative is not None),
            "positive_updates": np.int64(self._positive_updates)}
        for name, model in (("positive", positive), ("negative", negative)):
            row[f"{name}_ranks"] = np.array((0, 0, 0) if model is None else model.ranks, dtype=np.int64)
            modes = sample = error = np.full(len(states), np.nan)
            if model is not None and codes is not None:
                modes, sample = model.errors(codes)
                error = reconstruction_error(model, codes, gamma=p.gamma, mode=p.re_mode)
            row.update({f"{name}_error_modes": modes, f"{name}_error_sample": sample, f"{name}_error": error})
        row["log_likelihood"] = np.empty(0) if codes is None else self._scores(codes)[0]
        return row

    def sequence_rgb(self, frame: np.ndarray, method: str) -> np.ndarray:
        """``frame`` as RGB, checked to come after init and to have the first frame's size."""
        if self._frame_shape is None:
            raise RuntimeError(f"Tracker.{method}() called before init(): call init(first_frame, box_xywh) first")
        rgb = _as_rgb(frame)
        if rgb.shape[:2] != self._frame_shape:
            raise ValueError(
                f"frame has size {rgb.shape[1]}x{rgb.shape[0]} but the first frame was "
                f"{self._frame_shape[1]}x{self._frame_shape[0]}: every frame of a sequence must have the same size"
            )
        return rgb

    # ------------------------------------------------------------------ stages
    def _guide_round(self, rgb: np.ndarray, guide_box: np.ndarray, sigma: np.ndarray, shortlist: int):
        """The guide's box and ``guide_particles`` candidates around it, spread as the refine round's, with the
        first round's shortlist in proportion to their number: states, codes, labels, scores."""
        p = self.params
        centre = state_from_box_xywh(guide_box, p.template_size)
        share = min(1.0, p.guide_particles / p.n_particles)
        return self._round(rgb, centre, p.guide_particles, sigma * p.refine_sigma_scale, self._estimate,
                           _shared(shortlist, share), with_centre=True)[:4]

    def _draw(self, state: np.ndarray, n: int, sigma: np.ndarray) -> np.ndarray:
        p = self.params
        states = draw_candidates(state, n, sigma, self._rng, min_scale=1.0 / p.template_size)
        # Keep centres on the frame: a box whose centre left the image cannot be followed anyway.
        assert self._frame_shape is not None  # set by init, before any candidate is drawn
        height, width = self._frame_shape
        np.clip(states[:, 0], 1.0, width, out=states[:, 0])
        np.clip(states[:, 1], 1.0, height, out=states[:, 1])
        return states

    def _motion_sigma(self, state: np.ndarray) -> np.ndarray:
        """Random-walk std around ``state``: absolute (paper) or relative to the object's size and scale."""
        if not self.params.relative_motion:
            return self._sigma
        sigma = self._sigma.copy()
        sigma[:2] *= _size(state, self.params.template_size)
        sigma[2] *= state[2]
        return sigma

    def _redetect_sigma(self, anchor: np.ndarray) -> np.ndarray:
        """Wide std of the re-detection round: grows with the square root of the frames missed, up to the frame."""
        p = self.params
        spread = p.redetect_sigma * _size(anchor, p.template_size) * np.sqrt(self._misses - p.redetect_after + 1)
        sigma = self._motion_sigma(anchor).copy()
        assert self._frame_shape is not None  # set by init, before any re-detection
        sigma[:2] = min(spread, float(max(self._frame_shape)))
        return sigma

    def _level(self) -> tuple[float, float] | None:
        """Median and robust spread of the last accepted winners' log-likelihoods; None when disabled or empty."""
        p = self.params
        if p.level_window == 0 or not self._levels:
            return None
        median = float(np.median(self._levels))
        spread = _MAD_TO_STD * float(np.median(np.abs(np.asarray(self._levels) - median)))
        return median, max(spread, p.level_min_spread)

    def _round(self, rgb: np.ndarray, centre: np.ndarray, n: int, sigma: np.ndarray,
               estimate: tuple[np.ndarray, np.ndarray], shortlist: int, *, with_centre: bool = False):
        """Draw ``n`` candidates around ``centre`` and score them: states, codes, labels, scores, scoring.

        With the prescreen or a ``shortlist`` (its size, 0 for none), only the candidates they keep are scored and
        returned; ``estimate`` is the ``(T, T)`` superpixel map a shortlist's first pass cuts every candidate into,
        and its ``(z, s)`` codes. ``with_centre``: ``centre`` itself is a candidate too, the first, and never
        left out by the shortlist.
        """
        p = self.params
        states = self._draw(centre, n, sigma)
        if with_centre:
            states = np.concatenate([self._draw(centre, 1, np.zeros(6)), states])
        templates = None
        if self._reference is not None or 0 < shortlist < len(states):
            with self._time("warp"):
                templates = warp_candidates(rgb, states, p.template_size)
            if self._reference is not None:
                with self._time("prescreen"):
                    kept = self._reference.most_alike(templates, p.prescreen_share)
            else:
                with self._time("shortlist"):
                    kept = self._shortlisted(templates, *estimate, shortlist)
                    if with_centre:
                        kept = np.union1d([0], kept)
            states, templates = states[kept], templates[kept]
        return (states, *self._evaluate(rgb, states, templates))

    def _shortlisted(self, templates: np.ndarray, labels: np.ndarray, codes: np.ndarray, size: int) -> np.ndarray:
        """Indices, ascending, of the ``size`` templates that score best cut into ``labels`` (exact ties: the
        earlier), each superpixel's coding started from the atoms of ``codes``' and given ``shortlist_solves``
        solves beyond them, if set (a first look: the shortlist's own codes are computed from nothing, as every
        other code)."""
        p = self.params
        cut = np.broadcast_to(labels, (len(templates), *labels.shape))
        features = superpixel_features(templates, cut, self.n_superpixels, n_bins=p.n_bins)
        scores, _ = self._scores(encode_tensors(features, self._dictionary, lam=p.lasso_lambda, start=codes,
                                                max_solves=p.shortlist_solves or None))
        return np.sort(np.argsort(-scores, kind="stable")[:size])

    def _evaluate(self, rgb: np.ndarray, states: np.ndarray,
                  templates: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        """Code tensors, superpixel labels and log-likelihood of candidate states (``templates``: theirs, if
        already warped)."""
        codes, labels = self._codes(rgb, states, templates)
        with self._time("scoring"):
            return (codes, labels, *self._scores(codes))

    def _scores(self, codes: np.ndarray) -> tuple[np.ndarray, str]:
        """The score of each ``(N, z, s)`` code tensor under the run's models as they are, and how it was scored."""
        if self._positive is not None and self._negative is not None:
            return self._log_likelihood(codes), "subspace"
        # Bootstrap: histogram intersection with the first-frame code tensor (TPT).
        return np.minimum(codes, self._first_codes[None]).sum(axis=(1, 2)), "bootstrap"

    def _codes(self, rgb: np.ndarray, states: np.ndarray, templates: np.ndarray | None = None, *,
               time: StageTimer | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Code tensors and superpixel labels of ``states``, each distinct state computed once.

        Equal states warp to equal templates, and every later stage treats
        templates independently, so the copies are exact. About one negative
        in twenty repeats another (both of its centre coordinates are pushed
        out to the same margin). ``time``: the stage timer, the run's own by default.
        """
        unique, first, inverse = np.unique(states, axis=0, return_index=True, return_inverse=True)
        if len(unique) == len(states):
            features, labels = self._features(rgb, states, templates, time=time)
            return self._code(features, time=time), labels
        features, labels = self._features(rgb, unique, None if templates is None else templates[first], time=time)
        inverse = inverse.reshape(-1)
        return self._code(features, time=time)[inverse], labels[inverse]

    def _features(self, rgb: np.ndarray, states: np.ndarray, templates: np.ndarray | None = None, *,
                  time: StageTimer | None = None) -> tuple[np.ndarray, np.ndarray]:
        p, time = self.params, time or self._time
        if templates is None:
            with time("warp"):
                templates = warp_candidates(rgb, states, p.template_size)
        with time("snic"):
            labels = snic(templates, n_segments=p.n_superpixels, compactness=p.compactness, seeding=p.seeding)
        with time("features"):
            features = superpixel_features(templates, labels, self.n_superpixels, n_bins=p.n_bins)
        return features, labels

    def _code(self, features: np.ndarray, *, time: StageTimer | None = None) -> np.ndarray:
        """(N, s, B) features -> (N, z, s) code tensors (tensor pooling is arrangement)."""
        with (time or self._time)("coding"):
            return encode_tensors(features, self._dictionary, lam=self.params.lasso_lambda)

    def _log_likelihood(self, codes: np.ndarray) -> np.ndarray:
        """``RE- - RE+`` of each code tensor, the two models' errors computed on the kernel threads at once.

        Scoring is single-threaded BLAS work that would leave the second core idle. Each model scores all the
        candidates in one call: splitting the candidates instead would change the shapes of the
        matrix products, and with them OpenBLAS's kernel (its small-matrix path on AVX-512 machines) and the
        last bits of the scores.
        """
        p = self.params
        positive, negative = map_on_threads(
            lambda model: reconstruction_error(model, codes, gamma=p.gamma, mode=p.re_mode),
            self._scoring_models(), numba.get_num_threads())
        return negative - positive

    def _scoring_models(self) -> tuple[TensorSubspace | None, TensorSubspace | None]:
        """The positive and negative models as the run scores with them (None: not fitted yet); under
        ``negative_rank_matched`` the negative one truncated to the positive's ranks."""
        negative = self._negative
        if self.params.negative_rank_matched and negative is not None and self._positive is not None:
            negative = negative.truncated(self._positive.ranks)
        return self._positive, negative

    def _learn(self, rgb: np.ndarray, best_codes: np.ndarray) -> None:
        """Step 9 then step 10 of the per-frame schedule (TPT order)."""
        p = self.params
        self._accepted_count += 1
        self._buffer.append(best_codes)
        if len(self._buffer) == p.update_every:
            with self._time("positive_update"):
                batch = np.stack(self._buffer)
                if self._positive is None:
                    self._positive = TensorSubspace.fit(batch, p.ranks)
                else:
                    self._positive = self._positive.update(batch, p.ranks, p.forgetting)
            self._positive_updates += 1
            self._buffer = []
        refresh = self._negative is None or self._accepted_count % p.negative_every == 0
        if self._frame_number >= p.update_every and refresh:
            self._negative = self._fit_negative(rgb)

    def _fit_negative(self, rgb: np.ndarray) -> TensorSubspace:
        p = self.params
        negatives = draw_negatives(self._state, p.n_negatives, p.template_size, self._rng)
        codes, _ = self._codes(rgb, negatives)
        with self._time("negative_update"):
            return TensorSubspace.fit(codes, p.ranks)


def _shared(count: int, share: float) -> int:
    """``share`` of ``count`` candidates, rounded, at least one (none of none); all of them at ``share`` 1."""
    return count if share == 1 or count == 0 else max(1, round(count * share))


def _reported(results: list[FrameResult], chosen: int) -> FrameResult:
    """``results[chosen]``, carrying every run's box (``FrameResult.run_boxes_xywh``) when there are several."""
    if len(results) == 1:
        return results[0]
    return dataclasses.replace(results[chosen], run_boxes_xywh=np.stack([r.box_xywh for r in results]))


def _more_confident(results: list[FrameResult]) -> int:
    """Index of the run whose winner scores highest; subspace scores outrank bootstrap ones, first run on ties.

    The two stages score on different scales (``RE- - RE+`` against the intersection with the first frame's
    codes), so a subspace score always outranks a bootstrap one. Two bootstrap scores (the first
    ``update_every`` frames) are compared as they are, although each run's intersection is on the scale of
    its own dictionary's first-frame codes: the switch was measured so.
    """
    def rank(result: FrameResult) -> tuple[int, float]:
        ll = result.log_likelihood if np.isfinite(result.log_likelihood) else -np.inf
        return (1 if result.scoring == "subspace" else 0, ll)

    return max(range(len(results)), key=lambda i: rank(results[i]))  # max keeps the first of equal ranks


def _most_contrasted(results: list[FrameResult], rgb: np.ndarray, confident: int) -> int:
    """Index of the run whose box stands out most from its surroundings; the ``confident`` run on ties (see
    :func:`sptpt.contrast.most_contrasted`)."""
    return most_contrasted(rgb, [r.box_xywh for r in results], confident)


#: Two runs whose boxes overlap at least this much agree (``run_choice="consensus"``): the usual IoU for "the same
#: object" in tracking benchmarks.
_AGREE_IOU = 0.5


def _consensus(boxes: np.ndarray, n_runs: int, rgb: np.ndarray, confident: int) -> tuple[int, list[int]]:
    """The run to report and the boxes to average: the box the most other boxes agree with (IoU >=
    :data:`_AGREE_IOU`), and it with those boxes.

    ``boxes`` holds the runs' boxes, then any voters' (rows ``n_runs`` on: ``TrackerParams.filter_vote``).
    Among boxes with as many agreeing boxes, the one that stands out most (on equal contrast ``confident`` if it
    is one of them, else the first); a box no other agrees with is reported alone. With three runs: all agree,
    all three; one pair agrees, that pair; one run agrees with the two others (which do not agree), all three;
    none, the most contrasted run alone. A voter is never reported alone: where no run agrees with it, the runs
    decide among themselves. The run returned (whose score, confidence and acceptance the frame reports) is the
    chosen box's, or where that is a voter's, the first run that agrees with it: any run of the group would do,
    and the first needs no further rule.
    """
    agree = np.stack([np.nan_to_num(iou_xywh(boxes, b), nan=0.0) >= _AGREE_IOU for b in boxes])
    np.fill_diagonal(agree, False)
    votes = agree.sum(axis=1)
    tied = [i for i in range(len(boxes)) if votes[i] == votes.max()]
    default = confident if confident in tied else tied[0]
    chosen = tied[most_contrasted(rgb, boxes[tied], tied.index(default))]
    agreeing = [chosen, *np.flatnonzero(agree[chosen]).tolist()]
    if chosen < n_runs:
        return chosen, agreeing
    runs = [i for i in agreeing if i < n_runs]
    if not runs:  # the voter alone (or with voters only): as if it had not voted
        return _consensus(boxes[:n_runs], n_runs, rgb, confident)
    return runs[0], agreeing


#: The candidates re-ranked by contrast overlap the best-scoring one at least this much: contrast corrects a box that
#: straddles the object's edge; between distant places (a re-detection search) the subspace score decides.
_NEAR_IOU = 0.5


def _most_contrasted_candidate(rgb: np.ndarray, states: np.ndarray, scores: np.ndarray, best: int, k: int,
                               template_size: int) -> int:
    """Index of the candidate whose box stands out most from its surroundings, of ``best`` and the next best by
    score, ``k`` in all, that overlap ``best``'s box by at least :data:`_NEAR_IOU`.

    ``best`` wins ties and keeps the choice when no box's contrast can be measured, or its own box is degenerate.
    """
    order = np.argsort(-scores, kind="stable")
    top = np.concatenate([[best], order[order != best]])[:k]
    boxes = box_xywh_from_states(states[top], template_size)
    near = iou_xywh(boxes, boxes[0]) >= _NEAR_IOU
    near[0] = True  # a degenerate best box overlaps nothing, not even itself
    top, boxes = top[near], boxes[near]
    return int(top[most_contrasted(rgb, boxes, 0)])


def _size(state: np.ndarray, template_size: int) -> float:
    """Geometric-mean side sqrt(w h) of the box of an affine state, px."""
    return float(template_size * state[2] * np.sqrt(state[4]))


def _as_rgb(frame: np.ndarray) -> np.ndarray:
    if not isinstance(frame, np.ndarray):
        raise TypeError(f"frame must be a numpy array of uint8, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise TypeError(f"frame must have dtype uint8 (RGB 0-255), got {frame.dtype}; convert with "
                        "frame.astype(np.uint8)")
    if frame.ndim == 2:
        frame = np.repeat(frame[:, :, None], 3, axis=2)
    elif frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"frame must have shape (H, W, 3) RGB or (H, W) grayscale, got {frame.shape}")
    if frame.shape[0] < 2 or frame.shape[1] < 2:
        raise ValueError(f"frame must be at least 2x2 pixels, got {frame.shape[1]}x{frame.shape[0]}")
    return np.ascontiguousarray(frame)


def _validate_box(box_xywh, frame_shape: tuple[int, int]) -> np.ndarray:
    try:
        box = np.asarray(box_xywh, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"box_xywh must be 4 numbers x, y, w, h, got {box_xywh!r}") from None
    if box.shape != (4,):
        raise ValueError(f"box_xywh must be 4 numbers x, y, w, h, got {box.size} values: {box_xywh!r}")
    if not np.isfinite(box).all():
        raise ValueError(f"box_xywh must be finite, got {box.tolist()}")
    x, y, w, h = box
    if w <= 0 or h <= 0:
        raise ValueError(f"box_xywh must have positive width and height, got w={w:g}, h={h:g}")
    height, width = frame_shape
    if lies_outside(box, width, height):
        raise ValueError(
            f"box_xywh {box.tolist()} lies outside the {width}x{height} frame: "
            "give 0-based pixel coordinates of a box that overlaps the frame"
        )
    return box


def _validate_boxes(boxes_xywh) -> np.ndarray:
    """``boxes_xywh`` as an ``(N, 4)`` float64 array of finite boxes with positive size, or an error naming it."""
    try:
        boxes = np.asarray(boxes_xywh, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"boxes_xywh must be an (N, 4) array of x, y, w, h, got {boxes_xywh!r}") from None
    if boxes.ndim == 1 and boxes.shape == (4,):
        boxes = boxes[None]
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise ValueError(f"boxes_xywh must be an (N, 4) array of x, y, w, h, got shape {boxes.shape}")
    if not np.isfinite(boxes).all():
        raise ValueError("boxes_xywh must be finite, got NaN or infinite values")
    if (boxes[:, 2:] <= 0).any():
        bad = int(np.flatnonzero((boxes[:, 2:] <= 0).any(axis=1))[0])
        raise ValueError(f"boxes_xywh must have positive width and height, got box {bad} = {boxes[bad].tolist()}")
    return boxes
