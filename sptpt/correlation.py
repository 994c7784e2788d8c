"""The multichannel correlation filter both DSST filters are made of: learn, blend, respond.

Danelljan et al., "Accurate Scale Estimation for Robust Visual Tracking"
(BMVC 2014), learn one filter over the scale axis (:mod:`sptpt.scale`) and
one over a patch (:mod:`sptpt.translation`) by the same rule. For the
``(d, *axes)`` Fourier transform ``F`` of a windowed sample with ``d``
feature channels and the transform ``G`` of the desired (Gaussian) response,
the filter is the numerator ``A = conj(G) F`` and the denominator
``B = sum_l conj(F_l) F_l``; each later sample is blended in by a running
average with learning rate ``eta``, ``A <- (1 - eta) A + eta conj(G) F``
(likewise ``B``); and the response to a sample ``Z`` is
``y = IFFT(sum_l conj(A_l) Z_l / (B + lambda))``. What differs between the
two filters -- the axes, the label, the window, the features -- is given to
:class:`CorrelationFilter` by its user.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CorrelationFilter"]


class CorrelationFilter:
    """DSST's filter over the trailing axes of feature arrays: :meth:`learn`, then :meth:`blend` and :meth:`response`.

    Parameters
    ----------
    label : (*axes) ndarray of float
        The desired response to a sample at the learned position (DSST: a Gaussian). :meth:`response` to the
        learned sample approaches it where the sample's energy is far above ``lambda``, and to a circular shift
        of that sample it is shifted alike (exactly so under a window of ones; approximately under DSST's).
        Its shape is the shape of the filter's axes, one or two of them.
    window : (*axes) ndarray of float
        Multiplied into every channel of a sample before its Fourier transform (DSST: a Hann window).
    learning_rate : float
        ``eta`` in (0, 1], the new sample's weight in :meth:`blend` (DSST: 0.025).
    regularisation : float
        ``lambda`` > 0 added to the denominator in :meth:`response` (DSST: 0.01).

    Deterministic and stateful: :meth:`learn` and :meth:`blend` change the filter, :meth:`spectrum` and
    :meth:`response` only read it.
    """

    def __init__(self, label: np.ndarray, window: np.ndarray, *, learning_rate: float, regularisation: float) -> None:
        label = np.asarray(label, dtype=np.float64)
        window = np.asarray(window, dtype=np.float64)
        if label.ndim not in (1, 2) or window.shape != label.shape:
            raise ValueError(f"label and window must have the same 1-D or 2-D shape, got {label.shape} and "
                             f"{window.shape}")
        if not 0.0 < learning_rate <= 1.0:
            raise ValueError(f"learning_rate must lie in (0, 1], got {learning_rate}")
        if not 0.0 < regularisation < np.inf:
            raise ValueError(f"regularisation must be finite and > 0, got {regularisation}")
        self._axes = tuple(range(-label.ndim, 0))
        self._label = np.fft.fftn(label, axes=self._axes)
        self._window = window.copy()  # ours: a caller's later change to its array must not change the filter
        self.learning_rate = learning_rate
        self.regularisation = regularisation
        self._numerator: np.ndarray | None = None
        self._denominator: np.ndarray | None = None

    @property
    def learned(self) -> bool:
        """Whether :meth:`learn` has been called: :meth:`blend` and :meth:`response` need it."""
        return self._numerator is not None

    @property
    def numerator(self) -> np.ndarray | None:
        """``A``, complex ``(d, *axes)``; None before :meth:`learn`. Replaced, never changed in place, by
        :meth:`learn` and :meth:`blend`."""
        return self._numerator

    @property
    def denominator(self) -> np.ndarray | None:
        """``B``, real ``(*axes)``; None before :meth:`learn`. Replaced, never changed in place, by :meth:`learn`
        and :meth:`blend`."""
        return self._denominator

    def spectrum(self, features: np.ndarray) -> np.ndarray:
        """``(d, *axes)`` features -> complex ``(d, *axes)``: their windowed Fourier transform over the axes."""
        features = self._checked(features, channels=None, name="features")
        return np.fft.fftn(features * self._window[None], axes=self._axes)

    def learn(self, spectrum: np.ndarray) -> None:
        """Set the filter to the one learned from one sample's :meth:`spectrum` alone, forgetting any before (of
        any channel count)."""
        self._numerator, self._denominator = self._terms(self._checked(spectrum, channels=None))

    def blend(self, spectrum: np.ndarray) -> None:
        """Blend one sample's :meth:`spectrum` into ``A`` and ``B`` by the running average of rate ``eta``."""
        old_numerator, old_denominator = self._learned("blend")
        numerator, denominator = self._terms(self._checked(spectrum, channels=old_numerator.shape[0]))
        self._numerator = (1 - self.learning_rate) * old_numerator + self.learning_rate * numerator
        self._denominator = (1 - self.learning_rate) * old_denominator + self.learning_rate * denominator

    def response(self, spectrum: np.ndarray) -> np.ndarray:
        """The real ``(*axes)`` response ``IFFT(sum_l conj(A_l) Z_l / (B + lambda))`` to a sample's :meth:`spectrum`."""
        numerator, denominator = self._learned("response")
        spectrum = self._checked(spectrum, channels=numerator.shape[0])
        return np.fft.ifftn((np.conj(numerator) * spectrum).sum(axis=0)
                            / (denominator + self.regularisation), axes=self._axes).real

    def _terms(self, spectrum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The filter learned from one sample spectrum alone: ``A = conj(G) F``, ``B = sum conj(F) F``."""
        return np.conj(self._label)[None] * spectrum, (np.conj(spectrum) * spectrum).real.sum(axis=0)

    def _learned(self, method: str) -> tuple[np.ndarray, np.ndarray]:
        """``A`` and ``B``; a RuntimeError naming ``method`` before :meth:`learn` (which sets both together)."""
        if self._numerator is None or self._denominator is None:
            raise RuntimeError(f"CorrelationFilter.{method}() before learn()")
        return self._numerator, self._denominator

    def _checked(self, array: np.ndarray, *, channels: int | None, name: str = "spectrum") -> np.ndarray:
        """``array`` (a sample's features or spectrum, called ``name``) as an array of shape ``(channels, *axes)``
        (any channel count if None), or a ValueError."""
        # Broadcasting would silently accept a sample of other axes or, once learned, another channel count.
        array = np.asarray(array)
        if (array.ndim != self._window.ndim + 1 or array.shape[1:] != self._window.shape
                or (channels is not None and array.shape[0] != channels)):
            expected = ", ".join(map(str, ("d" if channels is None else channels, *self._window.shape)))
            raise ValueError(f"{name} must have shape ({expected}), got {array.shape}")
        return array
