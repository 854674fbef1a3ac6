"""Multiply-add rate of this CPU on the APG encoder's layer shapes, by kernel.

Usage: python benchmarks/matmul_rate.py [--rows 2400 38400] [--threads 1] [--int8]

For each (rows, in, out) of Table 2's per-row layers prints G multiply-adds/s of
``torch.addmm`` (MKL, behind ``nn.Linear``), oneDNN's fused linear+ReLU in float32 (the encoders'
inference path) and in bfloat16; with ``--int8`` also torch's dynamically quantised int8 linear layer
(VNNI kernels, whichever quantised engines this torch has; a deprecated torch API, measured only to
show whether int8 would open a faster path — it does not here). 2,400 rows = one lookahead decision
(80 actions x 6 pedestrians x 5 steps), 38,400 = 16 envs batched. The batched decision target (< 0.5 ms per env) needs 254 G/s.
"""

from __future__ import annotations

import argparse
import time
import warnings

import torch as th

LAYERS = ((19, 150), (150, 100), (100, 150), (100, 100))  # ψ_e (2 layers), ψ_h's hidden layer, ψ_α's 2nd layer


def rate(fn, macs: int, repeat: int = 30) -> float:
    for _ in range(3):
        fn()
    start = time.perf_counter()
    for _ in range(repeat):
        fn()
    return macs * repeat / (time.perf_counter() - start) / 1e9


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rows", type=int, nargs="+", default=[2400, 38400])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--int8", action="store_true", help="also time int8 dynamic quantisation per quantised engine")
    args = p.parse_args()
    th.set_num_threads(args.threads)
    onednn = th.ops.mkldnn._linear_pointwise
    print(f"torch_threads={th.get_num_threads()}  G multiply-adds/s: addmm (MKL) | oneDNN float32 | oneDNN bfloat16")
    for rows in args.rows:
        for fan_in, fan_out in LAYERS:
            x, w, b = th.randn(rows, fan_in), th.randn(fan_out, fan_in), th.randn(fan_out)
            xb, wb, bb = x.bfloat16(), w.bfloat16(), b.bfloat16()
            macs = rows * fan_in * fan_out
            with th.no_grad():
                mkl = rate(lambda: th.addmm(b, x, w.t()), macs)  # noqa: B023
                f32 = rate(lambda: onednn(x, w, b, "relu", [], ""), macs)  # noqa: B023
                try:
                    bf16 = f"{rate(lambda: onednn(xb, wb, bb, 'relu', [], ''), macs):6.0f}"  # noqa: B023
                except RuntimeError:
                    bf16 = "   n/a"
            print(f"rows {rows:6d}  {fan_in:3d} -> {fan_out:3d}: {mkl:6.0f} | {f32:6.0f} | {bf16}")
            if args.int8:
                print("      int8 dynamic: " + ", ".join(f"{engine} {rate_int8(engine, x, fan_in, fan_out):.0f}"
                                                      for engine in int8_engines()))


def int8_engines() -> list[str]:
    return [e for e in th.backends.quantized.supported_engines if e in ("fbgemm", "x86", "onednn")]


def rate_int8(engine: str, x: th.Tensor, fan_in: int, fan_out: int) -> float:
    """G multiply-adds/s of ``quantize_dynamic``'s int8 Linear on the quantised engine ``engine``."""
    th.backends.quantized.engine = engine
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the quantised-tensor API is deprecated
        layer = th.ao.quantization.quantize_dynamic(th.nn.Sequential(th.nn.Linear(fan_in, fan_out)), {th.nn.Linear},
                                                    dtype=th.qint8)
        with th.no_grad():
            return rate(lambda: layer(x), x.shape[0] * fan_in * fan_out)


if __name__ == "__main__":
    main()
