"""Frames in sequence: :class:`FrameIterator` (what every reader of ``lidarpkt.open`` is) and
:class:`FrameStack` (K frames of one sensor on one grid, the input of the temporal analysis)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np

from lidarpkt.errors import AnalysisError, UsageError
from .frame import Frame
from .sensor import SensorInfo

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self is Python 3.11+


class FrameIterator:
    """What every frame reader of :func:`lidarpkt.open` shares: iterate it for :class:`Frame` objects;
    ``close()`` it (or use ``with``) to stop early. A subclass sets ``_iter``, its frames, and ``close()``.

    A reader gives its frames once: a loop over a reader whose frames have all been taken, or that was
    closed, raises :class:`~lidarpkt.errors.UsageError` (rather than giving no frame, as an exhausted
    iterator would). A loop left early (``break``) and taken up again goes on where it left off."""

    _iter: Iterator[Frame]
    _ended: str | None = None  # "consumed" once the last frame was taken, "closed" once close() ran

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        close = cls.__dict__.get("close")
        if close is not None and not getattr(close, "_marks_closed", False):
            @functools.wraps(close)
            def closing(self, *args, **kw):
                self._ended = self._ended or "closed"
                return close(self, *args, **kw)

            closing._marks_closed = True  # type: ignore[attr-defined]
            cls.close = closing  # type: ignore[method-assign]

    def __iter__(self) -> Self:
        if self._ended:
            what = "its frames were all taken" if self._ended == "consumed" else "it was closed"
            path = getattr(self, "path", None) or getattr(getattr(self, "reader", None), "path", "lidarpkt.open()")
            raise UsageError(f"{path}: a reader of lidarpkt.open() gives its frames "
                             f"once, and {what}; call lidarpkt.open() again for another pass (or keep the frames "
                             "in a list)")
        return self

    def __next__(self) -> Frame:
        try:
            return next(self._iter)
        except StopIteration:
            self._ended = self._ended or "consumed"
            raise

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(eq=False)
class FrameStack:
    """K frames of one sensor on one column grid, stacked along a first axis: the input of
    the temporal analysis. Pixel (i, j) is the same raypath in every frame.

    Attributes:
        sensor, return_labels: as in :class:`Frame`.
        frame_id: ``int64[K]``.
        range_mm: ``uint32[K, R, H, W]``; reflectivity: ``uint8[K, R, H, W]``.
        column_valid: ``bool[K, W]``; column_timestamp_ns: ``int64[K, W]``;
        azimuth_deg: ``float64[K, W]``.
    """

    sensor: SensorInfo
    return_labels: tuple[str, ...]
    frame_id: np.ndarray
    range_mm: np.ndarray
    reflectivity: np.ndarray
    column_valid: np.ndarray
    column_timestamp_ns: np.ndarray
    azimuth_deg: np.ndarray

    def __len__(self) -> int:
        return int(self.range_mm.shape[0])

    @classmethod
    def from_frames(
        cls, frames: Iterable[Frame], *, resolution_deg: float | None = None, include_partial: bool = False
    ) -> "FrameStack":
        """Stack frames after putting each on the grid (see :meth:`Frame.on_grid`; by default
        :func:`default_grid_deg`, the grid of ``lidarpkt decode -o x.npz`` and ``lidarpkt analyze``).

        Partial frames are left out unless ``include_partial``. Raises
        :class:`~lidarpkt.errors.AnalysisError` if no frame is left or the frames differ in
        shape or return labels.
        """
        gridded = [f.on_grid(resolution_deg) for f in frames if include_partial or not f.partial]
        if not gridded:
            raise AnalysisError("no complete frames to stack (pass include_partial=True to use partial ones)")
        first = gridded[0]
        for f in gridded[1:]:
            if f.shape != first.shape or f.return_labels != first.return_labels:
                raise AnalysisError(
                    f"frame {f.frame_id} has shape {f.shape} and returns {f.return_labels}, "
                    f"unlike frame {first.frame_id} ({first.shape}, {first.return_labels}): "
                    "stack frames of one sensor and mode only"
                )
        return cls(
            sensor=first.sensor,
            return_labels=first.return_labels,
            frame_id=np.array([f.frame_id for f in gridded], dtype=np.int64),
            range_mm=np.stack([f.range_mm for f in gridded]),
            reflectivity=np.stack([f.reflectivity for f in gridded]),
            column_valid=np.stack([f.column_valid for f in gridded]),
            column_timestamp_ns=np.stack([f.column_timestamp_ns for f in gridded]),
            azimuth_deg=np.stack([f.azimuth_deg for f in gridded]),
        )
