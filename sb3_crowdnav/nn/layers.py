"""Small building blocks shared by the extractors: MLPs, masked softmax, distance-sorted LSTM pooling."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import torch as th
from torch import nn

from sb3_crowdnav.sim.validation import check_int


def check_arch(name: str, arch: Sequence[int], *, allow_empty: bool = False, last: int | None = None) -> list[int]:
    """Validate a list of layer sizes and return it as a list of ints."""
    if isinstance(arch, (str, bytes)) or not isinstance(arch, Sequence):
        raise TypeError(f"{name} must be a sequence of layer sizes, got {arch!r}")
    for i, size in enumerate(arch):
        check_int(f"{name}[{i}]", size, 1)
    sizes = [int(s) for s in arch]
    if not sizes and not allow_empty:
        raise ValueError(f"{name} must have at least one layer, got {arch!r}")
    if last is not None and (not sizes or sizes[-1] != last):
        raise ValueError(f"{name} must end with {last}, got {arch!r}")
    return sizes


def _probe_onednn() -> bool:
    """True when oneDNN's fused linear (+ReLU) kernel runs here (it is a private torch op)."""
    try:
        op = th.ops.mkldnn._linear_pointwise
        with th.no_grad():
            x, w, b = th.ones(2, 3), th.ones(4, 3), th.zeros(4)
            return bool(th.backends.mkldnn.is_available()) and th.equal(op(x, w, b, "relu", [], ""), x @ w.T)
    except (AttributeError, RuntimeError):
        return False


def _avx512() -> bool:
    """Whether torch runs its AVX-512 kernels on this CPU."""
    return th.backends.cpu.get_cpu_capability().startswith("AVX512")


_ONEDNN = {"available": _probe_onednn(), "enabled": _avx512(), "training": _avx512()}


def set_onednn_inference(enabled: bool) -> bool:
    """Switch the oneDNN fast path of :func:`linear` (no-grad CPU float32 only); returns whether it is in use.

    On by default where torch runs AVX-512 kernels: on AVX-512 AMD CPUs, MKL (behind ``nn.Linear``) runs its AVX2
    kernels and oneDNN is about twice as fast on these layer sizes. Off by default on other CPUs, where both run AVX2
    kernels and the fused kernel's cost per call makes it the slower of the two on a lookahead's batches
    (``benchmarks/README.md``). The results agree to float32 rounding.
    """
    _ONEDNN["enabled"] = bool(enabled)
    return _ONEDNN["enabled"] and _ONEDNN["available"]


def set_onednn_training(enabled: bool) -> bool:
    """Switch the oneDNN path of :func:`linear` when gradients are recorded; returns whether it is in use.

    The forward pass and both matrix products of the backward pass (input and weight gradients)
    then run on oneDNN's kernels instead of MKL's, about twice as fast on AVX-512 AMD CPUs
    (``benchmarks/training_speed.py``); gradients agree with ``nn.Linear``'s to float32 rounding. On by default where
    torch runs AVX-512 kernels, off elsewhere (on an AVX2 CPU MKL's gradient step was the faster by 6-7 %,
    ``benchmarks/README.md``), as :func:`set_onednn_inference`.
    """
    _ONEDNN["training"] = bool(enabled)
    return _ONEDNN["training"] and _ONEDNN["available"]


def exporting() -> bool:
    """Whether a graph is being traced for export (``torch.export``, ``torch.onnx.export``).

    The graph then reads the compacted width from the data at run time (:func:`compact_width`), the LSTM is one
    operator over the present slots (:func:`lstm_last_state_op`) and :func:`linear` runs ``nn.Linear`` on rows
    (oneDNN's private kernel has no ONNX form).
    """
    return th.compiler.is_exporting()


def compact_width(lengths: th.Tensor) -> int:
    """How many sorted pedestrian slots the extractors keep: the batch's largest count ``lengths`` (B,).

    In an exported graph this is a size read from the data at run time (the graph stays as fast as the eager
    compaction), and at least 1: an all-empty batch keeps one masked slot, so no shape is ever 0.
    """
    if exporting():
        return th.sym_max(lengths.max().item(), 1)
    return int(lengths.max()) if lengths.shape[0] > 0 else 0


def _onednn_eligible(x: th.Tensor) -> bool:
    return (
        _ONEDNN["available"]
        and not exporting()
        and x.dtype in (th.float32, th.bfloat16)
        and x.device.type == "cpu"
        and x.numel() > 0
        and not th.is_autocast_enabled("cpu")
    )


def _use_onednn(x: th.Tensor) -> bool:
    return _ONEDNN["enabled"] and not th.is_grad_enabled() and _onednn_eligible(x)


def _use_onednn_autograd(x: th.Tensor, layer: nn.Linear) -> bool:
    return (
        _ONEDNN["training"]
        and th.is_grad_enabled()
        and x.dtype == th.float32
        and layer.weight.dtype == th.float32
        and not x.is_inference()
        and _onednn_eligible(x)
    )


class _OneDnnLinear(th.autograd.Function):
    """``relu?(x @ weight.T + bias)`` with oneDNN kernels for the forward and the backward pass.

    Shapes: x (rows, in) contiguous, weight (out, in), bias (out,) or None -> (rows, out). The
    backward pass: grad_x = g @ weight, grad_weight = g.T @ x (oneDNN reads the transposed
    operands through their strides, no copy), grad_bias = g summed over the rows.
    """

    @staticmethod
    def forward(ctx, x: th.Tensor, weight: th.Tensor, bias: th.Tensor | None, relu: bool) -> th.Tensor:
        out = th.ops.mkldnn._linear_pointwise(x, weight, bias, "relu" if relu else "none", [], "")
        ctx.relu = relu
        ctx.save_for_backward(x, weight, out if relu else None)
        return out

    @staticmethod
    def backward(ctx, grad_out: th.Tensor):  # type: ignore[override]
        x, weight, out = ctx.saved_tensors
        if ctx.relu:
            grad = th.ops.aten.threshold_backward(grad_out, out, 0)  # zero where the ReLU was off
        else:
            grad = grad_out.contiguous()
        grad_x = grad_w = grad_b = None
        if ctx.needs_input_grad[0]:
            grad_x = th.ops.mkldnn._linear_pointwise(grad, weight.t().contiguous(), None, "none", [], "")
        if ctx.needs_input_grad[1]:
            grad_w = th.ops.mkldnn._linear_pointwise(grad.t(), x.t(), None, "none", [], "")
        if ctx.needs_input_grad[2]:  # False when there is no bias
            grad_b = grad.sum(dim=0)
        return grad_x, grad_w, grad_b, None


def bfloat16_supported() -> bool:
    """True when oneDNN has native bfloat16 matrix kernels on this CPU (AVX-512 BF16 or AMX)."""
    try:
        return bool(_ONEDNN["available"] and th.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def linear(x: th.Tensor, layer: nn.Linear, relu: bool = False) -> th.Tensor:
    """``layer(x)`` followed by an optional ReLU, fused in one oneDNN kernel on CPUs where it is the faster (AVX-512:
    :func:`set_onednn_inference`, :func:`set_onednn_training`), ``nn.Linear`` and an in-place ReLU elsewhere.

    Without gradients the fused kernel runs as it is; a bfloat16 ``x`` (inference only) is
    multiplied by bfloat16 copies of the float32 weights (oneDNN accumulates in float32 and
    rounds the output to bfloat16). With gradients, :class:`_OneDnnLinear` gives the fused
    forward a oneDNN backward pass (:func:`set_onednn_training` switches it off).
    """
    if exporting():  # as rows: ONNX Runtime fuses a 2-D product, its bias and the ReLU (before the reshape) into one Gemm
        out = layer(x.reshape(-1, x.shape[-1]))
        return (th.relu(out) if relu else out).reshape(*x.shape[:-1], layer.out_features)
    if _use_onednn(x):
        weight, bias = layer.weight, layer.bias
        if x.dtype == th.bfloat16:
            weight, bias = weight.to(th.bfloat16), None if bias is None else bias.to(th.bfloat16)
        return th.ops.mkldnn._linear_pointwise(x, weight, bias, "relu" if relu else "none", [], "")
    if x.dtype != layer.weight.dtype:
        raise TypeError(f"linear() got a {x.dtype} input for {layer.weight.dtype} weights outside the inference path")
    if _use_onednn_autograd(x, layer):
        # 2-D inside the Function: a view returned by a custom Function could not be modified in place
        out = _OneDnnLinear.apply(x.reshape(-1, x.shape[-1]).contiguous(), layer.weight, layer.bias, relu)
        return out.view(*x.shape[:-1], out.shape[-1])
    out = layer(x)
    return th.relu_(out) if relu else out  # in place is safe after a Linear


class MLP(nn.Module):
    """Linear layers of sizes ``arch`` with ReLU between them (and after the last one if ``last_activation``).

    An empty ``arch`` is the identity. Every layer goes through :func:`linear`: oneDNN's kernels where they are the
    faster (AVX-512 CPUs), plain ``nn.Linear`` with in-place ReLUs elsewhere (on these sizes a fresh activation
    tensor costs as much as the ReLU itself).

    :param input_dim: size of the input features
    :param arch: sizes of the layers
    :param last_activation: whether a ReLU follows the last layer
    """

    def __init__(self, input_dim: int, arch: Sequence[int], last_activation: bool = True) -> None:
        super().__init__()
        sizes = list(arch)
        dims = [input_dim, *sizes]
        self.layers = nn.ModuleList(nn.Linear(i, o) for i, o in itertools.pairwise(dims))
        self.relu = [last_activation or i < len(sizes) - 1 for i in range(len(sizes))]
        self.output_dim = sizes[-1] if sizes else input_dim

    def forward(self, x: th.Tensor) -> th.Tensor:
        for layer, relu in zip(self.layers, self.relu, strict=True):
            x = linear(x, layer, relu)
        return x


def mlp(input_dim: int, arch: Sequence[int], last_activation: bool = True) -> MLP:
    """Shorthand for :class:`MLP`."""
    return MLP(input_dim, arch, last_activation)


def masked_softmax(scores: th.Tensor, mask: th.Tensor, dim: int) -> th.Tensor:
    """Max-shifted softmax over ``dim`` restricted to ``mask``; all-zero weights where nothing is masked in."""
    scores = th.where(mask, scores, th.full((), -th.inf, dtype=scores.dtype))
    shift = scores.amax(dim=dim, keepdim=True)
    shift = th.where(th.isfinite(shift), shift, th.zeros((), dtype=scores.dtype))
    weights = th.exp(scores - shift)  # exactly 0 where masked out
    return weights / weights.sum(dim=dim, keepdim=True).clamp(min=th.finfo(scores.dtype).tiny)


def sort_farthest_first(offset: th.Tensor, present: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Order pedestrians for the LSTM: present ones farthest first (the nearest is seen last), padding after.

    The distances are compared squared, in float64: the products of the float32 offsets are exact and their sum
    rounded once, so an exported graph orders two pedestrians 1 float32 ulp apart as PyTorch does (``hypot``
    kernels differ in that bit); equal distances keep the slot order (a stable sort, ONNX's ``TopK``).

    :param offset: (B, N, 2) every slot's position relative to the robot (NaN in padded slots is masked)
    :param present: (B, N) bool
    :return: ``order`` (B, N) slot index at each sorted position, ``lengths`` (B,) number of present
        pedestrians, ``valid`` (B, N) bool, True at sorted positions holding a present pedestrian
    """
    x, y = offset[..., 0].double(), offset[..., 1].double()
    key = th.where(present, x * x + y * y, th.full((), -th.inf, dtype=x.dtype))
    order = th.sort(key, dim=1, descending=True, stable=True).indices
    lengths = present.sum(dim=1)
    valid = th.arange(present.shape[1], device=present.device)[None, :] < lengths[:, None]
    return order, lengths, valid


@th.library.custom_op("sb3_crowdnav::lstm_last_state", mutates_args=())
def lstm_last_state_op(sequence: th.Tensor, lengths: th.Tensor, weight_ih: th.Tensor, weight_hh: th.Tensor,
                       bias_ih: th.Tensor, bias_hh: th.Tensor, hidden_size: int) -> th.Tensor:
    """Hidden state of a one-layer, forward, batch-first LSTM with biases after the first ``lengths[b]`` items, as
    one operator for export (``torch.ops.sb3_crowdnav.lstm_last_state``).

    torch's exporter cannot trace ``nn.LSTM`` over a length read from the data (its decomposition unrolls the
    sequence); this operator stays whole in the exported program and :mod:`sb3_crowdnav.deploy.export` writes it as
    ONNX's ``LSTM`` with ``sequence_lens``, whose last state ``Y_h`` it is. Rows of length 0 are undefined here (the
    caller zeroes them).

    :param sequence: (B, L, F), valid items first
    :param lengths: (B,) long, at most L
    :param weight_ih: (4 hidden_size, F), torch's gate order (input, forget, cell, output); the other weights alike
    :return: (B, hidden_size)
    """
    zeros = sequence.new_zeros(1, sequence.shape[0], hidden_size)
    out = th.lstm(sequence, (zeros, zeros), [weight_ih, weight_hh, bias_ih, bias_hh], True, 1, 0.0, False, False,
                  True)[0]
    return out[th.arange(sequence.shape[0], device=sequence.device), (lengths - 1).clamp(min=0)]


@lstm_last_state_op.register_fake
def _lstm_last_state_shape(sequence, lengths, weight_ih, weight_hh, bias_ih, bias_hh, hidden_size):
    return sequence.new_empty(sequence.shape[0], hidden_size)


def lstm_last_state(lstm: nn.LSTM, sequence: th.Tensor, lengths: th.Tensor) -> th.Tensor:
    """Hidden state of a batch-first LSTM after the first ``lengths[b]`` items of each sequence.

    Items past a sequence's length are computed but never read (outputs of a unidirectional
    LSTM only depend on earlier items), which is faster here than packing or a masked
    LSTMCell loop. A sequence of length 0 gives the zero initial state. In an exported graph the LSTM is
    :func:`lstm_last_state_op` (ONNX's ``LSTM`` over the present items only, its last state read per row), which
    takes a one-layer, forward LSTM with biases.

    :param sequence: (B, N, F), valid items first
    :param lengths: (B,) long
    :return: (B, hidden_size)
    """
    batch = sequence.shape[0]
    if exporting():
        if lstm.num_layers != 1 or lstm.bidirectional or not lstm.bias or lstm.proj_size or not lstm.batch_first:
            raise ValueError(f"an exported graph holds a one-layer, forward, batch-first LSTM with biases, got {lstm}")
        last = lstm_last_state_op(sequence, lengths, lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0,
                                  lstm.bias_hh_l0, lstm.hidden_size)
    else:
        max_len = int(lengths.max()) if batch > 0 else 0
        if max_len == 0:
            return sequence.new_zeros(batch, lstm.hidden_size)
        out, _ = lstm(sequence[:, :max_len])  # (B, max_len, H)
        last = out[th.arange(batch, device=sequence.device), (lengths - 1).clamp(min=0)]  # (B, H)
    return th.where((lengths > 0)[:, None], last, th.zeros((), dtype=last.dtype))
