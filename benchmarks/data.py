"""Generated input data: scene frames and single-camera ROS 2 MCAP bags made of them.

A bag cycles through a small pool of pre-rendered scene frames (rendering a 1080p frame costs
more than writing it), with stamps and log times advancing at 30 frames per second.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal, NamedTuple

from replaybench.fixtures.writer import JPEG_FORMAT, stamp_ns

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

__all__ = ['JPEG_QUALITY', 'Bag', 'BagSpec', 'scene_frames', 'warm_page_cache', 'write_bag']

JPEG_QUALITY = 90
_FRAME_ID = 'camera_optical_frame'
_CHUNK_SIZE = 1 << 20


class BagSpec(NamedTuple):
    """What to write: one image topic of ``frames`` frames."""

    name: str
    size: tuple[int, int]
    frames: int
    encoding: Literal['rgb8', 'jpeg']
    compression: Literal['zstd'] | None = None

    @property
    def topic(self) -> str:
        return '/camera/image_raw/compressed' if self.encoding == 'jpeg' else '/camera/image_raw'

    def describe(self) -> str:
        width, height = self.size
        kind = 'CompressedImage jpeg' if self.encoding == 'jpeg' else 'Image rgb8'
        chunks = f'{self.compression} chunks' if self.compression else 'uncompressed chunks'
        return f'{width}x{height} {kind}, {self.frames} frames, {chunks}'


class Bag(NamedTuple):
    """A written bag."""

    spec: BagSpec
    path: Path
    size_bytes: int

    def as_dict(self) -> dict[str, Any]:
        return {
            'name': self.spec.name,
            'description': self.spec.describe(),
            'width': self.spec.size[0],
            'height': self.spec.size[1],
            'frames': self.spec.frames,
            'encoding': self.spec.encoding,
            'compression': self.spec.compression,
            'size_bytes': self.size_bytes,
        }


def scene_frames(size: tuple[int, int], count: int) -> list[npt.NDArray[np.uint8]]:
    """``count`` BGR frames of the synthetic fixture scene, a few frames apart."""
    from replaybench.fixtures.scene import Scene

    scene = Scene(size)
    return [scene.render(5 * i)[0] for i in range(count)]


def _payloads(spec: BagSpec, pool: Sequence[npt.NDArray[np.uint8]]) -> Iterator[bytes]:
    """Serialised messages, frame by frame; each pool frame is encoded once."""
    from replaybench.msgs import serialize_compressed_image, serialize_image

    if spec.encoding == 'jpeg':
        jpegs = [_jpeg(image) for image in pool]
        for i in range(spec.frames):
            yield serialize_compressed_image(
                stamp_ns(i), _FRAME_ID, jpegs[i % len(jpegs)], JPEG_FORMAT
            )
    else:
        import numpy as np

        rgbs = [np.ascontiguousarray(image[:, :, ::-1]) for image in pool]
        for i in range(spec.frames):
            yield serialize_image(stamp_ns(i), _FRAME_ID, rgbs[i % len(rgbs)], 'rgb8')


def _jpeg(image: npt.NDArray[np.uint8]) -> bytes:
    import cv2

    ok, data = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # pragma: no cover - OpenCV always encodes uint8 BGR
        msg = 'JPEG encoding failed'
        raise RuntimeError(msg)
    return bytes(data.tobytes())


def write_bag(path: Path, spec: BagSpec, pool: Sequence[npt.NDArray[np.uint8]]) -> Bag:
    """Write ``spec`` as a ROS 2 MCAP (CDR, ros2msg schema, 1 MiB chunks) at ``path``."""
    from mcap.writer import CompressionType, Writer

    from replaybench.msgs import COMPRESSED_IMAGE, IMAGE, ros2msg_schema

    msgtype = COMPRESSED_IMAGE if spec.encoding == 'jpeg' else IMAGE
    compression = CompressionType.ZSTD if spec.compression == 'zstd' else CompressionType.NONE
    with path.open('wb') as stream:
        writer: Any = Writer(stream, chunk_size=_CHUNK_SIZE, compression=compression)
        writer.start(profile='ros2', library='replaybench benchmarks')
        schema = writer.register_schema(
            name=msgtype, encoding='ros2msg', data=ros2msg_schema(msgtype).encode()
        )
        channel = writer.register_channel(
            topic=spec.topic, message_encoding='cdr', schema_id=schema
        )
        for i, data in enumerate(_payloads(spec, pool)):
            t = stamp_ns(i)
            writer.add_message(
                channel_id=channel, log_time=t, data=data, publish_time=t, sequence=i
            )
        writer.finish()
    return Bag(spec, path, path.stat().st_size)


def warm_page_cache(path: Path) -> None:
    """Read the whole file once so that every measurement starts from the page cache."""
    with path.open('rb', buffering=0) as f:
        while f.read(16 << 20):
            pass
