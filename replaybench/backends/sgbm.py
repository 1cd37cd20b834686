"""OpenCV's StereoSGBM on a stereo pair (``replaybench.stereo.matchers``), the stereo task.

A backend that takes frame sets (``--sync``): each set is a left and a right image, in that
order (``--stereo LEFT,RIGHT`` or stereo_image_proc's naming, docs/stereo.md). The pair's
geometry comes from the two frames' CameraInfo (``replaybench.stereo.stereo_pair``: the focal
length and baseline from the right camera's P) and, for raw images, the rectification maps are
built once per pair of topics (``Rectifier``); rectified pairs (``image_rect`` topics, or
CameraInfo with R identity, D zero and P = K) are used as they are.

Per pair: rectification and the conversion to mono8 (``preprocess``); the matcher
(``infer``); OpenCV's fixed point to float pixels, NaN where there is no match
(``postprocess``). The parameters are stereo_image_proc's defaults, changed by the backend
config's ``[sgbm]`` table (or its top-level keys; ``--config FILE``) and then by the backend
options (a sweep's ``--param sgbm.disparities=64,128``), by stereo_image_proc's names or
OpenCV's (``replaybench.stereo.matchers.PARAMETER_NAMES``).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import StereoError, UsageError
from replaybench.stereo.topics import pair_by_name
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.stereo import Matcher, Rectifier
    from replaybench.stereo.matchers import MatcherKind
    from replaybench.types import CameraInfo, Frame, FrameSet

__all__ = [
    'SgbmBackend',
    'StereoMatcherBackend',
    'StereoPairs',
    'matcher_parameters',
    'pair_rectifier',
]


def _option_value(key: str, text: str) -> object:
    """A backend option's text as the matcher takes it: true/false, or a whole number
    (``rectify_maps`` as it is)."""
    lowered = text.strip().lower()
    if key == 'rectify_maps':
        return lowered
    if lowered in {'true', 'false'}:
        return lowered == 'true'
    try:
        return int(lowered)
    except ValueError:
        msg = f'stereo parameter {key}={text!r} is not a whole number or true/false'
        raise UsageError(msg) from None


def matcher_parameters(kind: str, options: BackendOptions) -> dict[str, object]:
    """The parameters of the config file's ``[kind]`` table (or its top-level keys), then the
    backend options' (``extra``), by the names they were given."""
    table: dict[str, object] = {}
    if options.config is not None:
        import tomllib

        try:
            data = tomllib.loads(options.config.read_text(encoding='utf-8'))
        except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
            msg = f'{options.config}: cannot read the {kind} config: {err}'
            raise UsageError(msg) from None
        section = data.get(kind, data)
        if not isinstance(section, dict):
            msg = f'{options.config}: [{kind}] is not a table'
            raise UsageError(msg)
        table.update({k: v for k, v in section.items() if not isinstance(v, dict)})
    table.update({k: _option_value(k, v) for k, v in options.extra.items()})
    return table


def pair_rectifier(
    built: dict[tuple[int, str, str], Rectifier],
    left: Frame,
    right: Frame,
    maps: str = 'fixed',
) -> Rectifier:
    """The rectifier of a pair's left and right frames, built on its first set and kept in
    ``built`` by (input, left topic, right topic); ``StereoError`` for no CameraInfo, sizes
    that differ or no baseline. What every stereo backend rectifies with; ``maps``: the
    backend's ``rectify_maps`` option (``replaybench.stereo.RECTIFY_MAPS``)."""
    key = (left.input_index, left.topic, right.topic)
    found = built.get(key)
    if found is None:
        from replaybench.stereo import parse_stereo, stereo_pair

        named = parse_stereo(f'{left.topic},{right.topic}').rectified
        pair = stereo_pair(left.camera_info, right.camera_info, rectified=named or None)
        found = built[key] = pair.rectifier(maps)
    return found


class StereoPairs:
    """What every stereo backend declares and does with its pairs: synchronised left/right
    sets (paired by equal stamps without --sync), found by stereo_image_proc's names, checked
    before the replay, rectified with the maps its ``rectify_maps`` option names, built on a
    pair's first set. ``take_pairs`` in the backend's ``__init__`` sets the state."""

    name: ClassVar[str]
    takes_frame_sets: ClassVar[bool] = True
    reads_camera_info: ClassVar[bool] = True
    #: without --sync, a pair's images are paired by equal stamps (``--sync exact``)
    default_sync: ClassVar[str] = 'exact'

    #: without --topic or --stereo: the stereo pair the names of an input's camera topics
    #: make, left first
    frame_set_topics = staticmethod(pair_by_name)

    def take_pairs(self, rectify_maps: object) -> None:
        """No rectifier built yet; the maps ``rectify_maps`` names (None: ``fixed``;
        ``StereoError`` for another value)."""
        from replaybench.stereo import rectify_maps as maps_named

        #: the rectification maps (``fixed`` or ``float``; replaybench.stereo.calibration)
        self.rectify_maps = maps_named(rectify_maps, self.name)
        self._rectifiers: dict[tuple[int, str, str], Rectifier] = {}

    def check_frame_set(
        self, topics: tuple[str, ...], infos: tuple[CameraInfo | None, ...]
    ) -> None:
        """Before the replay: a left and a right topic, with CameraInfo of one size and a
        baseline (``StereoError``, one line, exit status 2, otherwise)."""
        from replaybench.stereo import stereo_pair

        if len(topics) != 2:
            msg = (
                f'{self.name} takes a left and a right image topic, not {len(topics)} '
                f'({", ".join(topics)}): give --stereo LEFT,RIGHT'
            )
            raise StereoError(msg)
        try:
            stereo_pair(*infos)
        except StereoError as err:
            msg = f'{self.name}: {topics[0]}, {topics[1]}: {err}'
            raise StereoError(msg) from None

    def rectifier(self, left: Frame, right: Frame) -> Rectifier:
        """The pair's rectifier, built on its first set (``pair_rectifier``)."""
        return pair_rectifier(self._rectifiers, left, right, self.rectify_maps)

    def rectified(self) -> list[bool]:
        """Whether each pair replayed so far was used as it was (run.json's ``rectified``)."""
        return sorted({r.pair.rectified for r in self._rectifiers.values()})


class StereoMatcherBackend(StereoPairs):
    """A stereo matcher of ``replaybench.stereo.matchers`` over synchronised pairs."""

    name: ClassVar[str]
    description: ClassVar[str]
    kind: ClassVar[MatcherKind]
    task: ClassVar[str] = 'stereo'

    def __init__(self, options: BackendOptions | None = None) -> None:
        from replaybench.stereo import Matcher

        self.options = options if options is not None else BackendOptions()
        table = matcher_parameters(self.kind, self.options)
        self.take_pairs(table.pop('rectify_maps', None))
        self.matcher: Matcher = Matcher.from_mapping(self.kind, table)

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def open(self) -> None:
        """Nothing to load: the matcher is built with the backend, the maps on a pair's first
        set."""

    def detect(self, frame_set: FrameSet) -> BackendResult:
        from replaybench.stereo import Disparity, to_mono8

        if len(frame_set.frames) != 2:
            msg = (
                f'{self.name} takes a left and a right image, not {len(frame_set.frames)} '
                f'({", ".join(frame_set.topics)}): give --stereo LEFT,RIGHT'
            )
            raise StereoError(msg)
        left, right = frame_set.frames
        began = time.perf_counter_ns()
        rectifier = self.rectifier(left, right)
        rect_left, rect_right = rectifier.rectify(left.image, right.image)
        grey_left = to_mono8(rect_left, left.encoding)
        grey_right = to_mono8(rect_right, right.encoding)
        t_infer = time.perf_counter_ns()
        fixed = self.matcher.compute_fixed(grey_left, grey_right)
        t_post = time.perf_counter_ns()
        from replaybench.stereo.matchers import DELTA_D, fixed_to_float

        params = self.matcher.params
        disparity = fixed_to_float(fixed, params.min_disparity)
        width, height = rectifier.pair.size
        output = Disparity.of_pair(
            disparity,
            rectifier.pair,
            min_disparity=params.min_disparity,
            max_disparity=params.max_disparity,
            delta_d=DELTA_D,
            valid_window=params.valid_window(width, height),
        )
        done = time.perf_counter_ns()
        stages = StageTimes(
            preprocess_ns=t_infer - began, infer_ns=t_post - t_infer, postprocess_ns=done - t_post
        )
        return BackendResult((), stages=stages, output=output)

    def info(self) -> dict[str, Any]:
        from dataclasses import asdict

        params: Mapping[str, Any] = asdict(self.matcher.params)
        return {
            'matcher': self.kind,
            'parameters': dict(params),
            'rectified': self.rectified(),
            'rectify_maps': self.rectify_maps,
        }

    def close(self) -> None:
        self._rectifiers.clear()


class SgbmBackend(StereoMatcherBackend):
    """OpenCV StereoSGBM with stereo_image_proc's defaults (CPU)."""

    name: ClassVar[str] = 'sgbm'
    description: ClassVar[str] = 'OpenCV StereoSGBM disparity of stereo pairs (CPU, --sync)'
    kind: ClassVar[MatcherKind] = 'sgbm'
