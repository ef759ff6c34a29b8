"""The appearance network run by OpenCV's DNN engine.

The network's layers (:class:`~tracker_service.cues.appearance.Layer`: 3 x 3 convolutions with
their batch norms folded in, ReLU, 2 x 2 max pooling, dense layers) are written as one ONNX graph,
every network of the ensemble a branch from the same input, built with the ``onnx`` package's
helpers and read by ``cv2.dnn.readNetFromONNX`` (OpenCV's optimised CPU convolutions). Its outputs
equal :func:`tracker_service.cues.appearance.forward`, the numpy reference (im2col + BLAS), to
float rounding (a test holds them within 1e-4); it is 3-4 times faster on one thread
(docs/BENCHMARKS.md, tracker speed).

The weights keep the training framework's layouts: convolutions ``(O, C, 3, 3)`` (ONNX's ``Conv``),
dense ``(O, I)`` (``Gemm`` with ``transB``), and the dense layers flatten in ``(C, H, W)`` order,
which is ONNX's ``Flatten`` of an ``NCHW`` tensor.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from tracker_service.cues.appearance import AppearanceNet, Layer

__all__ = ["AppearanceEngine", "onnx_graph"]

#: The ONNX operator set the graph uses (Conv, Relu, MaxPool, Flatten, Gemm).
OPSET = 13


def _branch(layers: tuple[Layer, ...], k: int, nodes: list[Any], inits: list[Any]) -> str:
    """Append network ``k``'s nodes and weights; the name of its output."""
    from onnx import helper, numpy_helper

    cur, flat = "x", False
    for i, layer in enumerate(layers):
        w, b = f"n{k}_w{i}", f"n{k}_b{i}"
        inits += [numpy_helper.from_array(np.asarray(layer.weight, np.float32), w),
                  numpy_helper.from_array(np.asarray(layer.bias, np.float32), b)]
        out = f"n{k}_l{i}"
        if layer.kind == "conv":
            nodes.append(helper.make_node("Conv", [cur, w, b], [out], kernel_shape=[3, 3], pads=[1, 1, 1, 1],
                                          strides=[layer.stride, layer.stride]))
        else:
            if not flat:
                nodes.append(helper.make_node("Flatten", [cur], [f"{out}_flat"], axis=1))
                cur, flat = f"{out}_flat", True
            nodes.append(helper.make_node("Gemm", [cur, w, b], [out], transB=1))
        cur = out
        if layer.relu:
            nodes.append(helper.make_node("Relu", [cur], [f"{out}_relu"]))
            cur = f"{out}_relu"
        if layer.kind == "conv" and layer.pool:
            nodes.append(helper.make_node("MaxPool", [cur], [f"{out}_pool"], kernel_shape=[2, 2], strides=[2, 2]))
            cur = f"{out}_pool"
    return cur


def onnx_graph(net: AppearanceNet, batch: int) -> bytes:
    """The ensemble as one serialised ONNX model.

    Parameters
    ----------
    net : AppearanceNet
    batch : int
        Views per call (1, or 2 with the mirrored crop).

    Returns
    -------
    bytes
        Input ``x`` ``(batch, 4, S, S)`` float32 (the crop channels-first); outputs ``y0``, ``y1``, ...
        ``(batch, n_outputs)``, one per network.
    """
    import onnx
    from onnx import TensorProto, helper

    nodes: list[Any] = []
    inits: list[Any] = []
    outputs = []
    for k, layers in enumerate(net.networks):
        last = _branch(layers, k, nodes, inits)
        nodes.append(helper.make_node("Identity", [last], [f"y{k}"]))
        outputs.append(helper.make_tensor_value_info(f"y{k}", TensorProto.FLOAT, [batch, net.n_outputs]))
    graph = helper.make_graph(nodes, "appearance", [helper.make_tensor_value_info(
        "x", TensorProto.FLOAT, [batch, 4, net.size, net.size])], outputs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="mocap-tracker")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return bytes(model.SerializeToString())


class AppearanceEngine:
    """The network compiled for OpenCV's DNN engine, one model per batch size.

    Parameters
    ----------
    net : AppearanceNet
    """

    def __init__(self, net: AppearanceNet) -> None:
        self.net = net
        self._models: dict[int, Any] = {}
        self._names = [f"y{k}" for k in range(len(net.networks))]

    def _model(self, batch: int) -> Any:
        if batch not in self._models:
            self._models[batch] = cv2.dnn.readNetFromONNX(np.frombuffer(onnx_graph(self.net, batch), np.uint8))
        return self._models[batch]

    def forward(self, x: NDArray[np.float32]) -> list[NDArray[np.float32]]:
        """Every network's raw output.

        Parameters
        ----------
        x : (N, S, S, 4) float32
            :func:`~tracker_service.cues.appearance.net_input` of ``N`` views.

        Returns
        -------
        list of (N, n_outputs) float32
            One per network, the first one's first (as :func:`~tracker_service.cues.appearance.forward`
            with ``member`` = 0, 1, ...).
        """
        model = self._model(int(x.shape[0]))
        model.setInput(np.ascontiguousarray(np.asarray(x, np.float32).transpose(0, 3, 1, 2)))
        outs = model.forward(self._names)
        return [np.asarray(o, np.float32).reshape(x.shape[0], -1) for o in outs]
