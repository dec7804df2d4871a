"""A TF.js graph model (``model.json`` + weight shards) run in torch, without TensorFlow.

TF.js graph models are a TensorFlow GraphDef as JSON (``modelTopology.node``) and their constants
as little-endian shards (``weightsManifest``), some quantised to uint8/uint16 or float16. ``TFJSGraph``
decodes the constants once and runs the nodes in order with torch, in TensorFlow's NHWC layout.
It knows the operations of the models recon ships (NanoDet, MoveNet single and multi-person); an unknown one is an error
at load time, not a wrong answer.
"""
from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from recon.errors import ReconError

DTYPES = {"float32": np.float32, "int32": np.int32, "bool": np.bool_, "uint8": np.uint8, "uint16": np.uint16,
          "float16": np.float16}
TF_DTYPES = {"DT_FLOAT": torch.float32, "DT_INT32": torch.int64, "DT_INT64": torch.int64, "DT_BOOL": torch.bool}


def read_weights(manifest: list[dict], folder: Path) -> dict[str, np.ndarray]:
    """The constants of a weights manifest, dequantised (``q * scale + min``, or float16) to float32."""
    out = {}
    for group in manifest:
        data = b"".join((folder / p).read_bytes() for p in group["paths"])
        at = 0
        for w in group["weights"]:
            shape = [int(s) for s in w["shape"]]
            q = w.get("quantization")
            stored = q["dtype"] if q else w["dtype"]
            dt = np.dtype(DTYPES[stored]).newbyteorder("<")
            n = int(np.prod(shape)) if shape else 1
            a = np.frombuffer(data, dt, count=n, offset=at).reshape(shape)
            at += n * dt.itemsize
            if q and stored != "float16":
                a = a.astype(np.float32) * np.float32(q["scale"]) + np.float32(q["min"])
            out[w["name"]] = a.astype(np.float32) if w["dtype"] == "float32" else a.astype(np.int64)
        if at != len(data):
            raise ReconError(f"weights of {folder}: {len(data)} bytes, the manifest describes {at}")
    return out


def _attr(node: dict, key: str, default=None):
    """A node attribute as a python value (TF.js JSON: {'i': '2'}, {'f': 0.1}, {'s': base64}, lists)."""
    a = node.get("attr", {}).get(key)
    if a is None:
        return default
    if "list" in a:
        lst = a["list"]
        if "i" in lst:
            return [int(v) for v in lst["i"]]
        if "s" in lst:
            return [base64.b64decode(v).decode() for v in lst["s"]]
        return []
    if "i" in a:
        return int(a["i"])
    if "f" in a:
        return float(a["f"])
    if "b" in a:
        return bool(a["b"])
    if "s" in a:
        return base64.b64decode(a["s"]).decode()
    if "type" in a:
        return a["type"]
    return a


def _same_pad(size: int, k: int, stride: int, dilation: int) -> tuple[int, int]:
    """TensorFlow's SAME padding on one axis (the extra pixel after, not before)."""
    out = -(-size // stride)
    total = max((out - 1) * stride + (k - 1) * dilation + 1 - size, 0)
    return total // 2, total - total // 2


def _conv(x: torch.Tensor, w: torch.Tensor, node: dict, depthwise: bool) -> torch.Tensor:
    """Conv2D / DepthwiseConv2dNative on NHWC ``x``; ``w`` HWIO (depthwise: H, W, C, multiplier)."""
    if _attr(node, "data_format", "NHWC") != "NHWC":
        raise ReconError(f"{node['name']}: only NHWC convolutions are supported")
    sh, sw = _attr(node, "strides")[1:3]
    dh, dw = (_attr(node, "dilations") or [1, 1, 1, 1])[1:3]
    kh, kw = w.shape[:2]
    x = x.permute(0, 3, 1, 2)
    padding = _attr(node, "padding")
    if padding == "SAME":
        t, b = _same_pad(x.shape[2], kh, sh, dh)
        left, right = _same_pad(x.shape[3], kw, sw, dw)
        x = F.pad(x, (left, right, t, b))
    elif padding == "EXPLICIT":
        p = _attr(node, "explicit_paddings")
        x = F.pad(x, (p[4], p[5], p[2], p[3]))
    if depthwise:
        c, m = w.shape[2:]
        y = F.conv2d(x, w.permute(2, 3, 0, 1).reshape(c * m, 1, kh, kw), stride=(sh, sw), dilation=(dh, dw), groups=c)
    else:
        y = F.conv2d(x, w.permute(3, 2, 0, 1), stride=(sh, sw), dilation=(dh, dw))
    return y.permute(0, 2, 3, 1)


def _fused(y: torch.Tensor, node: dict, extra: list[torch.Tensor]) -> torch.Tensor:
    """The ops a converter fused into a convolution (bias, then an activation)."""
    for op in _attr(node, "fused_ops", []):
        if op == "BiasAdd":
            y = y + extra[0]
        elif op == "Relu":
            y = F.relu(y)
        elif op == "Relu6":
            y = F.relu6(y)
        elif op == "Prelu":
            y = torch.where(y > 0, y, y * extra[1])
        elif op == "LeakyRelu":
            y = F.leaky_relu(y, _attr(node, "leakyrelu_alpha", 0.2))
        else:
            raise ReconError(f"{node['name']}: fused op {op} is not supported")
    return y


def _resize_bilinear(x: torch.Tensor, size: torch.Tensor, node: dict) -> torch.Tensor:
    h, w = (int(v) for v in size)
    align = _attr(node, "align_corners", False)
    if not align and not _attr(node, "half_pixel_centers", False):
        raise ReconError(f"{node['name']}: legacy ResizeBilinear (no half-pixel centres) is not supported")
    y = F.interpolate(x.permute(0, 3, 1, 2), size=(h, w), mode="bilinear", align_corners=align)
    return y.permute(0, 2, 3, 1)


def _max_pool(x: torch.Tensor, node: dict) -> torch.Tensor:
    kh, kw = _attr(node, "ksize")[1:3]
    sh, sw = _attr(node, "strides")[1:3]
    x = x.permute(0, 3, 1, 2)
    if _attr(node, "padding") == "SAME":
        t, b = _same_pad(x.shape[2], kh, sh, 1)
        left, right = _same_pad(x.shape[3], kw, sw, 1)
        x = F.pad(x, (left, right, t, b), value=float("-inf"))
    return F.max_pool2d(x, (kh, kw), (sh, sw)).permute(0, 2, 3, 1)


def _pad(x: torch.Tensor, pads: torch.Tensor, value: float = 0.0) -> torch.Tensor:
    flat = [int(v) for row in reversed(pads.tolist()) for v in row]  # last axis first, as F.pad wants
    return F.pad(x, flat, value=value)


def _sparse_to_dense(idx, shape, values, default):
    out = torch.full([int(s) for s in shape], default.item(), dtype=values.dtype)
    if idx.numel():
        out[tuple(idx.reshape(-1, len(shape)).T)] = values
    return out


def _gather_nd(params: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    return params[tuple(idx[..., i] for i in range(idx.shape[-1]))]


def _squeeze(x: torch.Tensor, node: dict) -> torch.Tensor:
    dims = _attr(node, "squeeze_dims") or [i for i, s in enumerate(x.shape) if s == 1]
    for d in sorted((d % x.dim() for d in dims), reverse=True):
        x = x.squeeze(d)
    return x


def _split_v(x: torch.Tensor, sizes: torch.Tensor, axis: torch.Tensor) -> list[torch.Tensor]:
    s = [int(v) for v in sizes]
    if -1 in s:
        s[s.index(-1)] = x.shape[int(axis)] - (sum(s) + 1)
    return list(torch.split(x, s, dim=int(axis)))


def _strided_slice(x: torch.Tensor, begin, end, strides, node: dict) -> torch.Tensor:
    """TensorFlow's StridedSlice with its begin/end/new-axis/shrink masks (no ellipsis, positive strides)."""
    masks = {k: _attr(node, k, 0) for k in ("begin_mask", "end_mask", "ellipsis_mask", "new_axis_mask",
                                             "shrink_axis_mask")}
    if masks["ellipsis_mask"] or any(int(s) <= 0 for s in strides):
        raise ReconError(f"{node['name']}: StridedSlice with an ellipsis or a negative stride is not supported")
    index = []
    for i, (b, e, s) in enumerate(zip(begin.tolist(), end.tolist(), strides.tolist())):
        bit = 1 << i
        if masks["new_axis_mask"] & bit:
            index.append(None)
        elif masks["shrink_axis_mask"] & bit:
            index.append(int(b))
        else:
            index.append(slice(None if masks["begin_mask"] & bit else int(b),
                               None if masks["end_mask"] & bit else int(e), int(s)))
    return x[tuple(index)]


def _reduce(f, x: torch.Tensor, axis: torch.Tensor, node: dict) -> torch.Tensor:
    dims = [int(a) % x.dim() for a in axis.reshape(-1)] if x.dim() else []
    keep = _attr(node, "keep_dims", False)
    for d in sorted(dims, reverse=True):
        x = f(x, d, keep)
    return x


def _top_k(x: torch.Tensor, k: torch.Tensor) -> list[torch.Tensor]:
    values, indices = torch.topk(x, int(k), dim=-1, sorted=True)
    return [values, indices]


def _select(cond: torch.Tensor, t: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """TensorFlow's Select: a vector condition picks rows (the first axis), else elementwise."""
    if cond.dim() == 1 and t.dim() > 1:
        cond = cond.reshape(-1, *[1] * (t.dim() - 1))
    return torch.where(cond, t, e)


def _int(x: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(x, dtype=torch.int64)


# op -> f(node, inputs) -> tensor or list of tensors (a node's outputs "name:i")
OPS = {
    "Identity": lambda n, a: a[0],
    "Cast": lambda n, a: a[0].to(TF_DTYPES[_attr(n, "DstT")]),
    "Add": lambda n, a: a[0] + a[1],
    "AddV2": lambda n, a: a[0] + a[1],
    "Sub": lambda n, a: a[0] - a[1],
    "Mul": lambda n, a: a[0] * a[1],
    "RealDiv": lambda n, a: a[0] / a[1],
    "FloorDiv": lambda n, a: torch.div(a[0], a[1], rounding_mode="floor"),
    "SquaredDifference": lambda n, a: (a[0] - a[1]) ** 2,
    "Sqrt": lambda n, a: torch.sqrt(a[0]),
    "Sigmoid": lambda n, a: torch.sigmoid(a[0]),
    "Relu": lambda n, a: F.relu(a[0]),
    "Relu6": lambda n, a: F.relu6(a[0]),
    "LeakyRelu": lambda n, a: F.leaky_relu(a[0], _attr(n, "alpha", 0.2)),
    "Abs": lambda n, a: torch.abs(a[0]),
    "Exp": lambda n, a: torch.exp(a[0]),
    "Reciprocal": lambda n, a: torch.reciprocal(a[0]),
    "AddN": lambda n, a: torch.stack(torch.broadcast_tensors(*a)).sum(0),
    "Maximum": lambda n, a: torch.maximum(*torch.broadcast_tensors(a[0], a[1].to(a[0].dtype))),
    "Minimum": lambda n, a: torch.minimum(*torch.broadcast_tensors(a[0], a[1].to(a[0].dtype))),
    "Equal": lambda n, a: a[0] == a[1],
    "Greater": lambda n, a: a[0] > a[1],
    "GreaterEqual": lambda n, a: a[0] >= a[1],
    "Less": lambda n, a: a[0] < a[1],
    "LogicalAnd": lambda n, a: torch.logical_and(a[0], a[1]),
    "Select": lambda n, a: _select(*a),
    "Sum": lambda n, a: _reduce(lambda x, d, k: x.sum(d, keepdim=k), a[0], a[1], n),
    "Max": lambda n, a: _reduce(lambda x, d, k: x.amax(d, keepdim=k), a[0], a[1], n),
    "TopKV2": lambda n, a: _top_k(a[0], a[1]),
    "Shape": lambda n, a: _int(list(a[0].shape)),
    "Size": lambda n, a: _int(a[0].numel()),
    "Fill": lambda n, a: torch.full([int(v) for v in a[0].reshape(-1)], a[1].item(), dtype=a[1].dtype),
    "Range": lambda n, a: torch.arange(a[0].item(), a[1].item(), a[2].item()),
    "Tile": lambda n, a: a[0].repeat(*[int(v) for v in a[1]]),
    "Split": lambda n, a: list(torch.chunk(a[1], _attr(n, "num_split"), dim=int(a[0]))),
    "StridedSlice": lambda n, a: _strided_slice(a[0], a[1], a[2], a[3], n),
    "Transpose": lambda n, a: a[0].permute(*[int(v) for v in a[1]]),
    "Reshape": lambda n, a: a[0].reshape([int(v) for v in a[1]]),
    "ExpandDims": lambda n, a: a[0].unsqueeze(int(a[1])),
    "Squeeze": lambda n, a: _squeeze(a[0], n),
    "ConcatV2": lambda n, a: torch.cat(a[:-1], dim=int(a[-1])),
    "Pack": lambda n, a: torch.stack(a, dim=_attr(n, "axis", 0)),
    "Unpack": lambda n, a: list(torch.unbind(a[0], dim=_attr(n, "axis", 0))),
    "SplitV": lambda n, a: _split_v(*a),
    "ArgMax": lambda n, a: torch.argmax(a[0], dim=int(a[1])),
    "GatherNd": lambda n, a: _gather_nd(a[0], a[1]),
    "Pad": lambda n, a: _pad(a[0], a[1]),
    "PadV2": lambda n, a: _pad(a[0], a[1], float(a[2])),
    "SparseToDense": lambda n, a: _sparse_to_dense(*a),
    "MaxPool": lambda n, a: _max_pool(a[0], n),
    "ResizeBilinear": lambda n, a: _resize_bilinear(a[0], a[1], n),
    "Conv2D": lambda n, a: _conv(a[0], a[1], n, depthwise=False),
    "DepthwiseConv2dNative": lambda n, a: _conv(a[0], a[1], n, depthwise=True),
    "_FusedConv2D": lambda n, a: _fused(_conv(a[0], a[1], n, depthwise=False), n, a[2:]),
    "FusedDepthwiseConv2dNative": lambda n, a: _fused(_conv(a[0], a[1], n, depthwise=True), n, a[2:]),
}


def _source(name: str) -> tuple[str, int]:
    """A node input "name:i" -> (node, output index); control inputs ("^name") are dropped earlier."""
    node, _, i = name.partition(":")
    return node, int(i) if i else 0


class TFJSGraph:
    """``TFJSGraph.load("model.json")(x) -> {output name: tensor}``: the graph on one input tensor
    (laid out as the model's signature says), under ``torch.inference_mode``."""

    def __init__(self, graph: dict, weights: dict[str, np.ndarray], name: str = "model"):
        self.name = name
        nodes = graph["modelTopology"]["node"]
        unknown = sorted({n["op"] for n in nodes} - set(OPS) - {"Const", "Placeholder"})
        if unknown:
            raise ReconError(f"{name}: TF.js operations not supported: {', '.join(unknown)}")
        self.consts = {k: torch.from_numpy(np.array(v, order="C")) for k, v in weights.items()}  # 0-d stays 0-d
        for n in nodes:
            if n["op"] == "Const" and n["name"] not in self.consts:
                raise ReconError(f"{name}: constant {n['name']} is missing from the weights")
        self.inputs = [n["name"] for n in nodes if n["op"] == "Placeholder"]
        self.nodes = [n for n in nodes if n["op"] not in ("Const", "Placeholder")]
        sig = graph.get("signature", {}).get("outputs", {})
        self.outputs = sorted({_source(o["name"])[0] for o in sig.values()}) or [self.nodes[-1]["name"]]
        self._order()

    def _order(self) -> None:
        """The nodes in an order where every input comes first (TF.js files need not keep one)."""
        known = set(self.consts) | set(self.inputs)
        by_name = {n["name"]: n for n in self.nodes}
        order, seen = [], set()

        def visit(name: str) -> None:
            if name in known or name in seen:
                return
            seen.add(name)
            for i in by_name[name].get("input", []):
                if not i.startswith("^"):
                    visit(_source(i)[0])
            order.append(by_name[name])

        for o in self.outputs:
            visit(o)
        self.nodes = order

    @classmethod
    def load(cls, path: str | Path) -> TFJSGraph:
        path = Path(path)
        if not path.is_file():
            raise ReconError(f"TF.js model {path} not found (scripts/setup.sh installs the shipped ones)")
        graph = json.loads(path.read_text())
        if graph.get("format") != "graph-model":
            raise ReconError(f"{path} is not a TF.js graph model (format {graph.get('format')!r})")
        return cls(graph, read_weights(graph["weightsManifest"], path.parent), path.stem)

    @torch.inference_mode()
    def __call__(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        values: dict[str, torch.Tensor | list[torch.Tensor]] = dict(self.consts)
        values[self.inputs[0]] = x
        for n in self.nodes:
            args = []
            for i in n.get("input", []):
                if i.startswith("^"):
                    continue
                src, k = _source(i)
                v = values[src]
                args.append(v[k] if isinstance(v, list) else v)
            values[n["name"]] = OPS[n["op"]](n, args)
        return {o: values[o] for o in self.outputs}
