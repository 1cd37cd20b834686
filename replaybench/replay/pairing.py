"""``--sync`` in a run: the header stamps of the frames each input replays, read before the
first frame, grouped into synchronised sets (``replaybench.replay.sync``), and what is refused.

The stamps are read off the messages' headers (``replaybench.decode.image.image_stamp``: 8
bytes of a ROS message, the timestamp field of a Foxglove one; no pixel is decoded), in one
pass over each input's replayed frames (the --start/--duration window and --max-frames as the
passes take them), before the backends are opened. Frames of different inputs never pair: each
input is grouped on its own. A message whose header cannot be read is left out of the pairing,
as the replay skips it.

Refused (``UsageError``, exit 2): a ``--topic`` that an input does not hold (without
``--sync`` such a topic is left out of that input), and an input whose topics share no stamp
(none within the slop). With one topic there is nothing to pair: every frame is a set of one,
said once in the run's warnings.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, NamedTuple

from replaybench.decode.image import image_stamp
from replaybench.errors import DecodeError, UsageError
from replaybench.replay.inputs import replayed
from replaybench.replay.sync import group_frames

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.sync import Grouping, SyncSpec
    from replaybench.results.model import SyncReport

__all__ = ['InputPairing', 'Pairing', 'pair_inputs', 'read_stamps', 'sync_report']

_NS = 1_000_000_000


class InputPairing(NamedTuple):
    """One input's sets, its messages whose header stamp could not be read, and per topic
    (in ``grouping.topics``' order) the ``seq`` of each frame whose stamp was read, in the
    order of ``group_frames``' indices."""

    input: int
    path: Path
    grouping: Grouping
    unreadable: int = 0
    seqs: tuple[tuple[int, ...], ...] = ()

    def members(self) -> dict[tuple[str, int], tuple[int, int]]:
        """Each frame in a set, by (topic, seq): (the set's index in ``grouping.sets``, the
        frame's place in the set, its topic's in ``grouping.topics``). A frame absent here
        found no partner."""
        topics = self.grouping.topics
        return {
            (topics[place], self.seqs[place][index]): (number, place)
            for number, found in enumerate(self.grouping.sets)
            for place, index in enumerate(found.indices)
        }


class Pairing(NamedTuple):
    """The sets of every input under ``spec``, the seconds the stamps took to read and group,
    and the warnings of the run (one topic: nothing to pair)."""

    spec: SyncSpec
    inputs: tuple[InputPairing, ...]
    read_s: float
    warnings: tuple[str, ...] = ()


def read_stamps(inp: OpenedInput) -> tuple[list[list[int]], int]:
    """Per replayed topic (in ``inp.topics``' order), the header stamps of its frames in replay
    order; and how many messages had no readable header stamp."""
    stamps, _, unreadable = _read_stamps(inp)
    return stamps, unreadable


def _read_stamps(inp: OpenedInput) -> tuple[list[list[int]], list[list[int]], int]:
    """``read_stamps``' stamps, with the ``seq`` of each frame beside its stamp."""
    names = [t.name for t in inp.topics]
    found: dict[str, tuple[list[int], list[int]]] = {name: ([], []) for name in names}
    unreadable = 0
    for raw in replayed(inp):
        try:
            stamp = image_stamp(raw)
        except DecodeError:
            unreadable += 1
            continue
        stamps, seqs = found[raw.topic]
        stamps.append(stamp)
        seqs.append(raw.seq)
    return [found[n][0] for n in names], [found[n][1] for n in names], unreadable


def _check_topics(inp: OpenedInput, wanted: Sequence[str] | None) -> None:
    if not wanted:
        return
    held = {t.name for t in inp.topics}
    missing = [w for w in wanted if w not in held]
    if missing:
        names = ', '.join(t.name for t in inp.topics)
        msg = (
            f'{inp.path}: --sync: no image topic named {", ".join(missing)} to pair '
            f'(replayed here: {names})'
        )
        raise UsageError(msg)


def _span(stamps: Sequence[int]) -> str:
    if not stamps:
        return 'no frame'
    return f'{min(stamps) / _NS:.6f} to {max(stamps) / _NS:.6f} s'


def _no_common_stamp(inp: OpenedInput, spec: SyncSpec, stamps: Sequence[Sequence[int]]) -> str:
    within = '' if spec.mode == 'exact' else f' within {spec.slop_ms:g} ms'
    spans = '; '.join(f'{t.name} {_span(s)}' for t, s in zip(inp.topics, stamps, strict=True))
    return (
        f'{inp.path}: --sync {spec.text}: topics {", ".join(t.name for t in inp.topics)} share '
        f'no header stamp{within}, so no frame set can be made (stamps: {spans})'
    )


def pair_inputs(
    inputs: Sequence[OpenedInput], spec: SyncSpec, wanted: Sequence[str] | None
) -> Pairing:
    """Every input's sets under ``spec``; ``wanted``: the --topic names, which every input must
    hold. ``UsageError`` for a topic missing and for topics with no stamp in common."""
    began = time.perf_counter()
    for inp in inputs:
        _check_topics(inp, wanted)
    paired: list[InputPairing] = []
    single: list[str] = []
    for inp in inputs:
        stamps, seqs, unreadable = _read_stamps(inp)
        names = [t.name for t in inp.topics]
        grouping = group_frames(names, stamps, spec)
        if len(names) == 1:
            single.append(names[0])
        elif not grouping.sets:
            raise UsageError(_no_common_stamp(inp, spec, stamps))
        paired.append(
            InputPairing(inp.number, inp.path, grouping, unreadable, tuple(tuple(s) for s in seqs))
        )
    warnings: tuple[str, ...] = ()
    if single:
        topics = ', '.join(dict.fromkeys(single))
        warnings = (
            (
                f'--sync {spec.text} with one topic ({topics}): nothing to pair, each frame is '
                'a set of one'
            ),
        )
    return Pairing(spec, tuple(paired), time.perf_counter() - began, warnings)


def sync_report(pairing: Pairing, backends: Sequence[tuple[str, bool]], policy: str) -> SyncReport:
    """run.json's ``sync`` section of ``pairing``; ``backends``: (label, takes frame sets)."""
    from replaybench.results.model import SyncInput, SyncReport, SyncTopic

    spec = pairing.spec
    return SyncReport(
        sync=spec.text,
        mode=spec.mode,
        slop_ms=spec.slop_ms,
        policy=policy,
        backends={label: 'sets' if sets else 'frames' for label, sets in backends},
        stamps_read_s=round(pairing.read_s, 6),
        inputs=tuple(
            SyncInput(
                input=p.input,
                sets=len(p.grouping.sets),
                spread_ms_max=(
                    None if (spread := p.grouping.spread_ns_max) is None else spread / 1e6
                ),
                topics=tuple(
                    SyncTopic(topic, frames, frames - unpaired, unpaired)
                    for topic, frames, unpaired in zip(
                        p.grouping.topics, p.grouping.frames, p.grouping.unpaired, strict=True
                    )
                ),
            )
            for p in pairing.inputs
        ),
    )
