"""The stereo task's part of recording a run: each pair's disparity written and scored.

A backend that declares the stereo task returns a ``Disparity`` (``replaybench.stereo.output``)
in ``BackendResult.output`` for each stereo pair (a frame set of ``--sync``, recorded under
its left image's key). ``StereoRecording.frame`` writes it into outputs.mcap
(``replaybench.tasks.stereo.sink``) and, where the input has truth for the left image
(``replaybench.tasks.stereo.truth``, by frame_id and stamp), scores it with
``replaybench.stereo.metrics``: the pair's figures go into its frames.csv row, its pixel sums
into the (backend, topic)'s, so that a row's figures are pooled over all its pixels. A pair
without an output (a recorded topic without the pair's message) has no estimate: its truth
pixels count as bad. Depth AbsRel is formed where the output has a focal length and a
baseline.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol, cast

import numpy as np

from replaybench.errors import BackendError
from replaybench.stereo.metrics import DisparityCounts, score_disparity
from replaybench.stereo.output import Disparity
from replaybench.tasks.base import TaskRecordingBase

if TYPE_CHECKING:
    from collections.abc import Mapping

    import numpy.typing as npt

    from replaybench.sinks.writer import OutputWriter
    from replaybench.stereo.metrics import StereoFigures
    from replaybench.types import BackendResult

__all__ = [
    'DisparityTruth',
    'KeptDisparity',
    'StereoRecording',
    'figures_of',
    'recording',
    'score_output',
]


class DisparityTruth(Protocol):
    """An input's truth disparity (``replaybench.tasks.stereo.truth.DisparityTopic``)."""

    #: the truth is depth in metres, converted with each output's f and baseline
    depth: bool

    def lookup(self, frame_id: str, stamp_ns: int) -> npt.NDArray[np.float32] | None: ...


class _Input(Protocol):
    @property
    def number(self) -> int: ...

    @property
    def truth(self) -> Mapping[str, object]: ...


def figures_of(figures: StereoFigures) -> dict[str, float | None]:
    """The figures by metric name (summary.csv's and frames.csv's columns)."""
    return {
        'epe': figures.epe,
        'bad1': figures.bad1,
        'bad2': figures.bad2,
        'bad3': figures.bad3,
        'd1_all': figures.d1_all,
        'density': figures.density,
        'abs_rel': figures.abs_rel,
    }


def score_output(output: Disparity | None, truth: npt.NDArray[np.float32]) -> DisparityCounts:
    """The counts of one pair against its truth (no output: no estimate anywhere); depth
    AbsRel from the output's f, t and cx_offset (``Disparity.depth``) where it has them."""
    if output is None:
        return score_disparity(np.full(truth.shape, np.nan, np.float32), truth)
    counts = score_disparity(output.disparity, truth, min_disparity=output.min_disparity)
    if not (output.f > 0 and output.t > 0):
        return counts
    gt = np.asarray(truth, dtype=np.float32)
    with np.errstate(invalid='ignore'):
        both = output.estimated() & np.isfinite(gt) & (gt != 0)
    z_est = output.depth()
    z_gt = replace(output, disparity=np.where(both, gt, np.nan).astype(np.float32)).depth()
    usable = both & np.isfinite(z_est) & np.isfinite(z_gt) & (z_gt > 0)
    zg, ze = z_gt[usable].astype(np.float64), z_est[usable].astype(np.float64)
    return replace(
        counts, depth_pixels=int(zg.size), abs_rel_sum=float(np.sum(np.abs(ze - zg) / zg))
    )


class KeptDisparity(NamedTuple):
    """A disparity kept after its pair was scored (the agreement, the streaming scores): its
    estimated pixels as zlib'd float32 (NaN without an estimate) and the geometry that makes
    depth of it."""

    shape: tuple[int, ...]
    packed: bytes
    f: float
    t: float
    cx_offset: float

    @classmethod
    def of(cls, output: Disparity) -> KeptDisparity:
        import zlib

        values = np.where(output.estimated(), output.disparity, np.nan).astype(np.float32)
        packed = zlib.compress(np.ascontiguousarray(values).tobytes(), 1)
        return cls(values.shape, packed, output.f, output.t, output.cx_offset)

    def values(self) -> npt.NDArray[np.float32]:
        """The disparity, NaN without an estimate."""
        import zlib

        return np.frombuffer(zlib.decompress(self.packed), np.float32).reshape(self.shape)


class StereoRecording(TaskRecordingBase):
    """Each (backend label, topic)'s pixel sums over its pairs with truth."""

    #: a stereo backend has no boxes to score
    scores_boxes = False
    writes_first = False

    def __init__(
        self, backends: int = 1, streams: Mapping[tuple[str, str], object] | None = None
    ) -> None:
        self.counts: dict[tuple[str, str], DisparityCounts] = {}
        #: with several backends, or for the streaming scores of a (backend, topic) with picks
        #: (``Recorder.picks``, filled before a pass's frames are recorded), each (backend,
        #: topic)'s disparities by (input, seq), zlib'd (``KeptDisparity``)
        self.keep = backends > 1
        self.streams: Mapping[tuple[str, str], object] = {} if streams is None else streams
        self.kept: dict[tuple[str, str], dict[tuple[int, int], KeptDisparity]] = {}
        self.unconverted: dict[str, int] = {}
        #: the truth of the pair last recorded (``frame`` runs before ``sample``)
        self._truth: npt.NDArray[np.float32] | None = None

    def frame(
        self,
        writer: OutputWriter,
        label: str,
        inp: _Input,
        key: tuple[str, int, int, int, str],
        result: BackendResult,
    ) -> Mapping[str, Any]:
        """One pair: its DisparityImage written and, against the left image's truth, scored;
        its frames.csv columns. ``BackendError`` for an output that is no ``Disparity``."""
        from replaybench.tasks.stereo.sink import write_disparity

        topic, _, log_time_ns, stamp_ns, frame_id = key
        output = result.output
        if output is not None and not isinstance(output, Disparity):
            msg = (
                f'backend {label!r} declares task stereo but returned '
                f'{type(output).__name__}, not a Disparity (replaybench.stereo.Disparity)'
            )
            raise BackendError(msg)
        if output is not None:
            write_disparity(writer, label, topic, log_time_ns, stamp_ns, frame_id, output)
            if self.keep or (label, topic) in self.streams:
                self._keep(label, topic, (inp.number, key[1]), output)
        table = cast('DisparityTruth | None', inp.truth.get('stereo'))
        truth = None if table is None else table.lookup(frame_id, stamp_ns)
        self._truth = truth
        if truth is None:
            return {}
        if getattr(table, 'depth', False):
            truth = self._truth = self._depth_truth(label, output, truth)
            if truth is None:
                return {}
        counts = score_output(output, truth)
        row = (label, topic)
        self.counts[row] = self.counts.get(row, DisparityCounts()) + counts
        return figures_of(counts.figures())

    def _keep(self, label: str, topic: str, frame: tuple[int, int], output: Disparity) -> None:
        self.kept.setdefault((label, topic), {})[frame] = KeptDisparity.of(output)

    def agreements(self) -> list[dict[str, Any]]:
        """Per topic and pair of stereo backends (run order): the pairs both returned, the
        figures of the second's disparities against the first's as truth."""
        rows: list[dict[str, Any]] = []
        groups = list(self.kept)
        for i, (first, topic) in enumerate(groups):
            for second, other_topic in groups[i + 1 :]:
                if other_topic != topic:
                    continue
                a, b = self.kept[(first, topic)], self.kept[(second, topic)]
                both = sorted(set(a) & set(b))
                total = DisparityCounts()
                for frame in both:
                    reference, other = a[frame].values(), b[frame].values()
                    if reference.shape == other.shape:
                        total += score_disparity(other, reference, min_disparity=-np.inf)
                figures = figures_of(total.figures())
                rows.append(
                    {'backend_a': first, 'backend_b': second, 'topic': topic, 'frames': len(both)}
                    | {k: figures[k] for k in ('epe', 'bad1', 'bad2', 'bad3', 'density')}
                )
        return rows

    def run_fields(self) -> Mapping[str, Any]:
        """run.json's ``stereo_agreement`` where two stereo backends replayed a topic."""
        rows = self.agreements()
        if not rows:
            return {}
        from replaybench.results.model import StereoAgreementRow

        return {'stereo_agreement': tuple(StereoAgreementRow(**row) for row in rows)}

    def sample(self, result: BackendResult) -> tuple[Disparity, Any] | None:
        """The sample pair's disparity and its truth (None without), for its thumbnail; None
        without an output."""
        output = result.output
        if not isinstance(output, Disparity):
            return None
        return output, self._truth

    def _depth_truth(
        self, label: str, output: Disparity | None, depth: npt.NDArray[np.float32]
    ) -> npt.NDArray[np.float32] | None:
        """Truth depth as disparity with the output's f and baseline; without an output, the
        depth itself (only which pixels hold truth matters: they all count as bad); None,
        counted, for an output without f or baseline."""
        from replaybench.tasks.stereo.truth import depth_to_disparity

        if output is None:
            return depth
        if not (output.f > 0 and output.t > 0):
            self.unconverted[label] = self.unconverted.get(label, 0) + 1
            return None
        return depth_to_disparity(depth, output.f, output.t, output.cx_offset)

    def warnings(self) -> list[str]:
        """Pairs whose truth depth could not be made a disparity."""
        return [
            f'{label}: {n} pair(s) not scored: truth is depth and the output has no focal '
            'length or baseline to convert it'
            for label, n in sorted(self.unconverted.items())
        ]

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        """The row's figures pooled over its pairs with truth; None where none was scored."""
        counts = self.counts.get((backend, topic))
        if counts is None:
            return None
        return figures_of(counts.figures())


class _Recorder(Protocol):
    @property
    def backends(self) -> int: ...

    @property
    def picks(self) -> Mapping[tuple[str, str], object]: ...


def recording(recorder: _Recorder) -> StereoRecording:
    """The stereo task's ``TaskRecording`` for the run of ``recorder``: it keeps disparities
    for the agreement when the run has several backends."""
    return StereoRecording(recorder.backends, recorder.picks)
