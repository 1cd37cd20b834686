"""Stereo models on the GPU engines of ``cuda-stereo`` / ``tensorrt-stereo``: the pipeline.

A model is read as ``onnx-stereo`` reads it (``replaybench.backends.onnx_stereo``:
``load_stereo_spec``, the layouts ``two-inputs`` and ``six-channel``, fixed input sizes).

Per left/right pair (``StereoPipeline``):

* on the host, before the first GPU call: rectification with the pair's maps (``Rectifier``,
  ``cv2.remap``, the same maps and bytes as ``onnx-stereo``) and the conversion to the model's
  channels (``network_channels``: grey as ``to_mono8``, colour in its channel order);
* ``h2d``: both uint8 images copied into reused pinned buffers, then to the device;
* ``preprocess`` (device): HWC -> CHW, the resize to the network's size (torch's ``area``, an
  adaptive average, rounded to whole grey levels; none when the image has the network's size)
  and ``pixel * scale``, written into the bound input tensors (the two inputs, or the two
  halves of the one 6-channel input);
* ``infer``: the engine (``StereoOrtEngine``: onnxruntime with both inputs bound;
  ``StereoTorchEngine``: the converted module, as ``TorchEngine``);
* ``postprocess`` (device): the disparity plane, resized bilinearly to the image (half-pixel
  centres, as OpenCV's ``INTER_LINEAR``) and multiplied by the width ratio;
* ``d2h``: the image-sized float32 disparity; then, on the host, the ``Disparity``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.backends.gpu._engines import OrtEngine, TorchEngine, import_onnx2torch
from replaybench.backends.gpu._engines import _version as module_version
from replaybench.backends.gpu._fold import fold_shapes
from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.backends.onnx_stereo import StereoModelSpec

__all__ = [
    'StereoOrtEngine',
    'StereoPipeline',
    'StereoTorchEngine',
    'network_channels',
    'stereo_facts',
    'stereo_output_names',
    'torch_stereo_module',
]

Tensor = Any  # torch.Tensor


def network_channels(image: npt.NDArray[Any], encoding: str, order: str) -> npt.NDArray[np.uint8]:
    """An image as a stereo network's channels: HxW grey (``to_mono8``), or HxWx3 in
    ``order`` (``rgb`` / ``bgr``), uint8; as ``onnx-stereo`` converts it."""
    from replaybench.decode import to_bgr8
    from replaybench.stereo import to_mono8

    if order == 'grey':
        return np.ascontiguousarray(to_mono8(image, encoding))
    bgr = to_bgr8(image, encoding)
    return np.ascontiguousarray(bgr[:, :, ::-1] if order == 'rgb' else bgr)


def stereo_output_names(path: Path) -> list[str]:
    """Names of all graph outputs in graph order (onnx2torch returns them in this order)."""
    onnx = importlib.import_module('onnx')
    model = onnx.load(str(path), load_external_data=False)
    return [o.name for o in model.graph.output]


def torch_stereo_module(
    name: str, path: Path, spec: StereoModelSpec, torch: Any
) -> tuple[Any, dict[str, Any]]:
    """The stereo model as a torch module: its inputs fixed at their shapes and its shape
    arithmetic folded (``fold_shapes``), converted by onnx2torch; and the facts of it."""
    onnx = importlib.import_module('onnx')
    proto = onnx.load(str(path))
    onnx2torch, torchvision = import_onnx2torch()
    graph_inputs = [i.name for i in proto.graph.input]
    shapes = [spec.input_shapes[spec.input_names.index(n)] for n in graph_inputs]
    try:
        proto, report = fold_shapes(onnx, proto, *shapes)
    except BackendError as exc:
        msg = f'{name}: cannot fold the shapes of {path.name}: {exc}'
        raise BackendError(msg) from exc
    try:
        module = onnx2torch.convert(proto)
    except Exception as exc:  # unsupported ops and the like
        msg = f'{name}: onnx2torch cannot convert {path}: {type(exc).__name__}: {exc}'
        raise BackendError(msg) from exc
    facts = {
        'torch': str(torch.__version__),
        'onnx2torch': module_version('onnx2torch'),
        'torchvision': module_version('torchvision') if torchvision is not None else None,
        'shape_folding': {
            'input_shapes': [list(s) for s in shapes],
            'folded_nodes': report.folded,
            'shape_ops_left': report.shape_ops_left,
        },
    }
    return module, {'graph_inputs': graph_inputs, **facts}


class StereoOrtEngine(OrtEngine):
    """onnxruntime with IO binding: the stereo model's one or two inputs and its disparity
    output stay on the device (``OrtEngine``'s call)."""

    def __init__(
        self,
        session: Any,
        input_names: Sequence[str],
        inputs: Sequence[Tensor],
        output_name: str,
        torch: Any,
    ) -> None:
        self.torch = torch
        self.session = session
        self.names = [output_name]
        self.device = inputs[0].device
        kind = 'cuda' if self.device.type == 'cuda' else 'cpu'
        index = self.device.index or 0
        binding = session.io_binding()
        for name, tensor in zip(input_names, inputs, strict=True):
            dtype = np.float16 if tensor.dtype == torch.float16 else np.float32
            binding.bind_input(name, kind, index, dtype, list(tensor.shape), tensor.data_ptr())
        binding.bind_output(output_name, kind, index)
        self.binding = binding
        self._values: list[Any] = []


class StereoTorchEngine(TorchEngine):
    """``TorchEngine`` over the converted stereo module, fed all its inputs (graph order)."""

    def __init__(
        self,
        torch: Any,
        module: Any,
        inputs: Sequence[Tensor],
        names: Sequence[str],
        cuda_graph: bool,
    ) -> None:
        self.inputs = tuple(inputs)
        super().__init__(torch, module, self.inputs[0], names, cuda_graph)

    def _forward(self) -> list[Tensor]:
        with self.torch.inference_mode():
            out = self.module(*self.inputs)
        return list(out) if isinstance(out, list | tuple) else [out]


def stereo_facts(spec: StereoModelSpec) -> dict[str, Any]:
    """What ``info()`` records of a stereo model (``onnx-stereo``'s keys)."""
    return {
        'model_sha256': spec.sha256,
        'layout': spec.layout,
        'layout_source': spec.layout_source,
        'inputs': [
            {'name': n, 'shape': list(s)}
            for n, s in zip(spec.input_names, spec.input_shapes, strict=True)
        ],
        'input_size': list(spec.size),
        'output': {'name': spec.output_name, 'shape': list(spec.output_shape)},
        'channel_order': spec.channel_order,
        'scale': spec.scale,
        'max_disparity': spec.max_disparity,
        'rectification': "on the host: cv2.remap with the pair's maps, as onnx-stereo",
        'resize': 'on the device: area (adaptive average, rounded half up) to the network, '
        'bilinear back, values x width ratio',
    }


class StereoPipeline:
    """Upload, preprocessing and the disparity of one stereo model on one torch device (the
    CPU in tests: no pinned memory there)."""

    def __init__(self, torch: Any, spec: StereoModelSpec, device: Any, half: bool) -> None:
        self.torch = torch
        self.spec = spec
        self.device = device
        dtype = torch.float16 if half else torch.float32
        #: the tensors the engines bind, in ``spec.input_names`` order
        self.inputs = tuple(
            torch.empty(shape, dtype=dtype, device=device) for shape in spec.input_shapes
        )
        self._pinned: list[Tensor] = [None, None]

    def stage(self, images: Sequence[npt.NDArray[np.uint8]]) -> list[Tensor]:
        """The host side of the upload: each image copied into its reused pinned buffer
        (CUDA), or a CPU tensor of its own; no GPU call."""
        torch = self.torch
        if self.device.type != 'cuda':
            return [torch.from_numpy(np.array(image)) for image in images]
        staged = []
        for index, image in enumerate(images):
            pinned = self._pinned[index]
            if pinned is None or tuple(pinned.shape) != image.shape:
                pinned = torch.empty(image.shape, dtype=torch.uint8, pin_memory=True)
                self._pinned[index] = pinned
            np.copyto(pinned.numpy(), image)
            staged.append(pinned)
        return staged

    def transfer(self, staged: Sequence[Tensor]) -> list[Tensor]:
        """The staged images copied to the device, queued on the current stream."""
        if self.device.type != 'cuda':
            return list(staged)
        return [host.to(self.device, non_blocking=True) for host in staged]

    def preprocess(self, images: Sequence[Tensor]) -> None:
        """Both images at the network's size, scaled, written into the input tensors."""
        torch = self.torch
        spec = self.spec
        width, height = spec.size
        c = spec.channels
        for index, image in enumerate(images):
            planes = image[None] if image.ndim == 2 else image.permute(2, 0, 1)
            values = planes.to(torch.float32)[None]
            if int(image.shape[0]) != height or int(image.shape[1]) != width:
                values = torch.nn.functional.interpolate(values, size=(height, width), mode='area')
                values = torch.floor(values + 0.5)  # whole grey levels, as OpenCV rounds
            values = values[0] * spec.scale
            if len(self.inputs) == 2:
                target = self.inputs[index][0]
            else:
                target = self.inputs[0][0, index * c : (index + 1) * c]
            target.copy_(values)

    def postprocess(self, outputs: Mapping[str, Tensor], size: tuple[int, int]) -> Tensor:
        """The image-sized disparity (width, height ``size``) on the device."""
        torch = self.torch
        out = outputs.get(self.spec.output_name)
        if out is None:
            msg = f'the engine gave no output {self.spec.output_name!r}'
            raise BackendError(msg)
        if any(int(v) != 1 for v in out.shape[:-2]):
            msg = f'output {self.spec.output_name!r} has shape {list(out.shape)}; expected H x W'
            raise BackendError(msg)
        net = out.reshape(int(out.shape[-2]), int(out.shape[-1])).to(torch.float32)
        width, height = size
        ratio = width / int(net.shape[1])
        if int(net.shape[0]) != height or int(net.shape[1]) != width:
            net = torch.nn.functional.interpolate(
                net[None, None], size=(height, width), mode='bilinear', align_corners=False
            )[0, 0]
        return net * ratio if ratio != 1 else net

    def download(self, tensor: Tensor) -> npt.NDArray[np.float32]:
        """The disparity copied to the host, in memory of its own (on the CPU the tensor may
        be the engine's output buffer, which the next pair overwrites)."""
        host = tensor.detach().to('cpu')
        if self.device.type != 'cuda':
            host = host.clone()
        return np.asarray(host.numpy(), dtype=np.float32)
