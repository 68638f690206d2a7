"""The transport network of Eq. 4-7: T_k(x, w_o) = f(h_k(x), SH(w_r), n, rho), h_k = U (S(x) * W[k]).

S is a multiresolution hash grid over the scene's box (M = levels x features), W a learned M-vector per
cube-map wavelet (the CP factor over wavelets, Eq. 6), U an M x M map without bias, f an MLP whose three
outputs are the signed wavelet transport of one channel each. The outgoing indirect radiance is
B = sum over the selected wavelets of L_k T_k (Eq. 3), linear in L for a fixed selection.

S(x) and the per-pixel inputs are computed once per pixel and broadcast over wavelets (the public demo
recomputes them per pixel-wavelet pair).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from workers.models.prt.config import PrtConfig
from workers.nn.precision import native_bfloat16

PIXEL_INPUTS = ("normal", "kd", "ks")  # with the SH of w_r and the mapped roughness
WAVELET_INIT_STD = 0.1
MAX_PAIRS_PER_CHUNK = 1 << 18  # pixel-wavelet pairs through f at once (memory of the MLP's activations)
CPU_CHUNK_BYTES = 1 << 20  # a chunk's hidden activations on a CPU (`pairs_per_chunk`)


def roughness_feature(sigma: Tensor) -> Tensor:
    """log(25 sigma + 1) / log 26 (Sec. 4): 0 at a mirror, 1 at sigma = 1, spreading small roughnesses."""
    return torch.log1p(25.0 * sigma.clamp(0.0, 1.0)) / math.log(26.0)


class PrtNetwork(nn.Module):
    def __init__(self, config: PrtConfig) -> None:
        super().__init__()
        self.grid = config.grid.build(3)
        m = self.grid.n_output_dims
        self.wavelet_factors = nn.Parameter(WAVELET_INIT_STD * torch.randn(config.n_wavelets, m))  # W
        self.mix = nn.Linear(m, m, bias=False)  # U
        self.directions = config.directions.build()
        n_pixel = self.directions.n_output_dims + 3 * len(PIXEL_INPUTS) + 1
        self.f = config.mlp.build(m + n_pixel, 3)
        # Start from T = 0 (no indirect light, the trivial baseline): with random outputs the sum over
        # wavelets starts far off and, on quick's 768 rows, never recovered (held-out indirect PSNR 9.8 dB
        # against 15.2 with a zero output layer and 15.6 with W ~ N(0, 0.1) as well, 300 steps).
        nn.init.zeros_(self.f.layers[-2].weight)
        self.bfloat16 = config.bfloat16_products

    def pair_flops(self) -> int:
        """Floating-point operations of one pixel-wavelet pair in `forward`: f's products from the h part of
        its first layer on (the rest of that layer is once per pixel) and the pair's term of the sum over
        wavelets. A frame's network cost in a unit that is the same on every machine (`frame_spp`)."""
        linears = [layer for layer in self.f.layers if isinstance(layer, nn.Linear)]
        first = self.grid.n_output_dims * linears[0].out_features
        return 2 * (first + sum(layer.in_features * layer.out_features for layer in linears[1:]) + 3)

    def pixel_features(self, inputs: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """S(x) [P, M] and the rest of f's per-pixel inputs [P, F]."""
        spatial = self.grid(inputs["position"])
        rest = torch.cat(
            [
                self.directions(inputs["reflected"]),
                *(inputs[name] for name in PIXEL_INPUTS),
                roughness_feature(inputs["roughness"]),
            ],
            dim=-1,
        )
        return spatial, rest

    def first_layer(self, rest: Tensor, wavelets: Tensor) -> tuple[Tensor, Tensor]:
        """f's first layer on [h_k, rest], split: its rest part [P, width], computed once per pixel, and its
        h part with U and W[k] folded in (W_h U diag(W[k]), one [width, M] matrix per wavelet), as one
        [M, K width] matrix, so the first layer of all pixel-wavelet pairs is the product of S(x) with it,
        without materialising the [P, K, M] CP features (same values as f(cat(U(S * W[k]), rest)); 30%
        less network time per frame)."""
        first, m = self.f.layers[0], self.grid.n_output_dims
        per_pixel = rest @ first.weight[:, m:].T + first.bias  # [P, width]
        folded = first.weight[:, :m] @ self.mix.weight  # W_h U: [width, M]
        per_wavelet = self.wavelet_factors[wavelets][:, None, :] * folded[None]  # [K, width, M] (Eq. 6-7)
        return per_pixel, per_wavelet.reshape(-1, m).T

    def transport(
        self, spatial: Tensor, rest: Tensor, wavelets: Tensor, shares: list[int] | None = None
    ) -> Tensor:
        """T_k [P, K, 3] of pixels (their `pixel_features`) for flat wavelet indices `wavelets` [K], or [G, K]
        for G groups of consecutive pixels of sizes `shares` (a training batch's lightings), each through its
        own wavelets. Training's form: with few pixels per wavelet set (16 a lighting by default) the CP
        features [p, K, M] are smaller than `first_layer`'s folded [K, width, M]; they go through f in
        cache-sized chunks of pixels (`pairs_per_chunk`; default preset, one thread, CPU ms of f's forward
        and backward: all lightings as one product 34-37, a lighting a chunk 28-30)."""
        groups = wavelets.view(-1, wavelets.shape[-1])
        k, shares = groups.shape[-1], [len(spatial)] if shares is None else shares
        first, m = self.f.layers[0], self.grid.n_output_dims
        folded = first.weight[:, :m] @ self.mix.weight  # W_h U: [width, M]
        per_pixel = rest @ first.weight[:, m:].T + first.bias  # [P, width]
        chunk = max(1, pairs_per_chunk(spatial.device, first.out_features, spatial.dtype.itemsize) // k)
        out, start = [], 0
        for share, factors in zip(shares, self.wavelet_factors[groups], strict=True):  # W[k] (Eq. 6)
            for a in range(start, start + share, chunk):
                b = min(a + chunk, start + share)
                cp = spatial[a:b, None, :] * factors  # S(x) * W[k]: [p, K, M]
                out.append(self.f.layers[1:](cp @ folded.T + per_pixel[a:b, None, :]))
            start += share
        return torch.cat(out)

    def forward(self, inputs: dict[str, Tensor], wavelets: Tensor, coefficients: Tensor) -> Tensor:
        """B [P, 3] = sum_k L_k T_k (Eq. 3) for lighting `coefficients` [K, 3] at `wavelets` [K], in chunks
        of pixels: the first layer's factors once, then f's layers a chunk at a time. With `bfloat16`, f's
        first and hidden products run in bfloat16 where the device has it natively (`native_bfloat16`);
        its output layer and the sum over wavelets stay in the network's dtype."""
        spatial, rest = self.pixel_features(inputs)
        per_pixel, per_wavelet = self.first_layer(rest, wavelets)
        k, coefficients = len(wavelets), coefficients.to(spatial.dtype)
        low = self.bfloat16 and spatial.dtype == torch.float32 and native_bfloat16(spatial.device)
        product_dtype = torch.bfloat16 if low else spatial.dtype
        spatial, per_wavelet = spatial.to(product_dtype), per_wavelet.to(product_dtype)
        hidden_layers, output_layer = self.f.layers[1:-2], self.f.layers[-2:]
        pairs = pairs_per_chunk(spatial.device, per_pixel.shape[-1], product_dtype.itemsize)
        chunk = max(1, pairs // max(k, 1))
        out = per_pixel.new_empty(len(spatial), 3)
        for start in range(0, len(spatial), chunk):
            end = min(start + chunk, len(spatial))
            hidden = (spatial[start:end] @ per_wavelet).view(end - start, k, -1)
            hidden = hidden.add_(per_pixel[start:end, None, :].to(product_dtype))
            with torch.autocast(spatial.device.type, torch.bfloat16, enabled=low):
                hidden = hidden_layers(hidden)
            t = output_layer(hidden.to(out.dtype))
            out[start:end] = torch.einsum("pkc,kc->pc", t, coefficients)
        return out


def pairs_per_chunk(device: torch.device, width: int, itemsize: int) -> int:
    """Pixel-wavelet pairs through f at once: on a CPU, few enough that a chunk's activations stay in its
    L2 cache (default preset's f, 64 wide, 48^2 pixels x K = 64, one thread, CPU ms a frame; float32: 2^18
    pairs a chunk 97-104, 2^14 58-68, 2^13 46-52, 2^12 (1 MiB) 41-42, 2^11 40-42, 2^10 45-48; bfloat16:
    2^18 42-51, 2^14 19-20, 2^13 (1 MiB) 20-22, 2^12 21-22, 2^11 25-26); elsewhere as many as memory
    allows."""
    if device.type != "cpu":
        return MAX_PAIRS_PER_CHUNK
    return max(1, CPU_CHUNK_BYTES // (width * itemsize))
