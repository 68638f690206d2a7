"""Neural toolkit throughput: the hash grid's CPU kernels against its PyTorch path and a straightforward
reference, the kernels' first-run compile time, and the MLP against matmul peak."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import time
from contextlib import nullcontext
from functools import partial

import numba
import torch

from tests.bench.common import BenchSection, median_seconds
from workers.nn.encodings.grid import pytorch_path_on_cpu
from workers.nn.encodings.hashgrid import HashGrid
from workers.nn.encodings.hashgrid_reference import reference_hashgrid_encode
from workers.nn.mlp import MLP

HASHGRID_POINT_COUNTS = (2**16, 2**18)
MLP_BATCH = 2**16
MATMUL_SIZE = 2048


def _instant_ngp_grid() -> HashGrid:
    """instant-ngp's default 3D configuration: 16 levels of 2 features, 2^19 rows, resolutions 16..2048."""
    return HashGrid(3, 16, 2, 19, base_resolution=16, per_level_scale=math.exp(math.log(2048 / 16) / 15))


def _forward_backward(encode, grid: HashGrid, x: torch.Tensor):
    def run() -> None:
        grid.table.grad = None
        encode(x).sum().backward()

    return run


def _timed(fn, kernels: bool, clock=time.perf_counter) -> float:
    with nullcontext() if kernels else pytorch_path_on_cpu():
        return median_seconds(fn, repeats=3, clock=clock)


def bench_hashgrid() -> BenchSection:
    section = BenchSection("hash grid 3D (16 levels x 2 features, table 2^19): points/s")
    grid = _instant_ngp_grid()
    reference = partial(reference_hashgrid_encode, grid)
    torch.manual_seed(0)
    for n in HASHGRID_POINT_COUNTS:
        x = torch.rand(n, 3)
        figures = {}
        for path, encode, kernels in (
            ("kernels", grid, True),
            ("pytorch", grid, False),
            ("reference", reference, False),
        ):
            with torch.no_grad():
                figures[path, "forward"] = _timed(partial(encode, x), kernels)
            figures[path, "forward+backward"] = _timed(_forward_backward(encode, grid, x), kernels)
        with torch.no_grad():
            figures["cpu", "forward"] = _timed(partial(grid, x), True, time.process_time)
        figures["cpu", "forward+backward"] = _timed(_forward_backward(grid, grid, x), True, time.process_time)
        for mode in ("forward", "forward+backward"):
            kernels, pytorch, ref = (figures[path, mode] for path in ("kernels", "pytorch", "reference"))
            section.add(
                points=n,
                mode=mode,
                kernels_pts_s=n / kernels,
                kernels_pts_cpu_s=n / figures["cpu", mode],
                pytorch_pts_s=n / pytorch,
                reference_pts_s=n / ref,
                kernels_over_pytorch=pytorch / kernels,
            )
    section.notes.append("kernels = workers/nn/encodings/grid_kernels.py (Numba, the CPU path)")
    section.notes.append("pytorch = the same interpolation as per-level tensor operations (the CUDA path)")
    section.notes.append("reference = loops over corners, plain indexing, autograd backward (same formula)")
    section.notes.append(
        "kernels_pts_cpu_s = points per CPU-second of the process (all threads summed): on a machine"
        " shared with other jobs it moves far less than wall time; with T threads and no other load,"
        " wall-clock points/s is at most T times it"
    )
    section.notes.append(
        f"torch threads: {torch.get_num_threads()}; numba threads: {numba.get_num_threads()}"
    )
    section.notes.append("medians of 3 (wall clock unless stated)")
    return section


_FIRST_CALL = """
import time, torch
from tests.bench.bench_nn import _instant_ngp_grid
grid, x = _instant_ngp_grid(), torch.rand(4096, 3, requires_grad=True)
start = time.perf_counter()
grid(x).sum().backward()
print(time.perf_counter() - start)
"""


def bench_kernel_compile() -> BenchSection:
    """The kernels compile once per machine (Numba's on-disk cache); a fresh cache pays it once."""
    section = BenchSection("hash grid CPU kernels: first call in a new process (forward + backward)")
    with tempfile.TemporaryDirectory() as cache:
        for state in ("empty cache (compiles)", "warm cache (loads)"):
            start = time.perf_counter()
            first_call = subprocess.run(
                [sys.executable, "-c", _FIRST_CALL],
                env={**os.environ, "NUMBA_CACHE_DIR": cache},
                capture_output=True,
                text=True,
                check=True,
            ).stdout
            section.add(cache=state, first_call_s=float(first_call), process_s=time.perf_counter() - start)
    return section


def _matmul_gflops() -> float:
    a, b = torch.randn(MATMUL_SIZE, MATMUL_SIZE), torch.randn(MATMUL_SIZE, MATMUL_SIZE)
    seconds = median_seconds(lambda: a @ b, repeats=5)
    return 2 * MATMUL_SIZE**3 / seconds / 1e9


def bench_mlp() -> BenchSection:
    section = BenchSection(f"MLP 4x128 (32 in, 3 out), batch {MLP_BATCH}: against {MATMUL_SIZE}^2 matmul")
    torch.manual_seed(0)
    net = MLP(32, 3, width=128, depth=4)
    x = torch.randn(MLP_BATCH, 32)
    weights = sum(m.weight.numel() for m in net.modules() if isinstance(m, torch.nn.Linear))
    forward_flops = 2 * weights * MLP_BATCH
    peak = _matmul_gflops()

    def forward_backward() -> None:
        net.zero_grad(set_to_none=True)
        net(x).sum().backward()

    with torch.no_grad():
        fwd = median_seconds(lambda: net(x), repeats=5)
    fb = median_seconds(forward_backward, repeats=5)
    # Backward costs two matmuls per layer (input and weight gradients): 3x the forward FLOPs.
    for mode, seconds, flops in (
        ("forward", fwd, forward_flops),
        ("forward+backward", fb, 3 * forward_flops),
    ):
        achieved = flops / seconds / 1e9
        section.add(
            mode=mode,
            samples_s=MLP_BATCH / seconds,
            gflop_s=achieved,
            matmul_gflop_s=peak,
            fraction_of_matmul=achieved / peak,
        )
    return section


def run() -> list[BenchSection]:
    return [bench_hashgrid(), bench_kernel_compile(), bench_mlp()]
