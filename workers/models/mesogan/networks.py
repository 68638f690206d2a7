"""MesoGAN's networks (Diolatzis 2022, Sec. 6.2.4-6.2.8), re-implemented (no StyleGAN3 code is vendored).

- `PlaneGenerator`: a StyleGAN3-style synthesis network whose input is a Fourier-feature map of absolute
  plane positions. Its frequencies and phases are re-drawn every training iteration (no absolute position
  bias: any window of the infinite plane can be generated), and every layer adds new random Fourier
  features in its own band (f_{l-1}, f_l] (Sec. 6.2.5). Convolutions are unpadded and the input window
  is widened by the receptive field, so a window's features depend only on the positions it covers: two
  windows agree on their overlap and a large window equals stitched small ones.
- `Mapping`: the latent code and the structure parameters to the style w (Sec. 6.2.8).
- `Decoder`: plane features and the integrated encoding of height to density; appearance, light and view
  directions enter only the radiance head, so they cannot change geometry. rho is the albedo-weighted
  transport (Eq. 6.4), so the head predicts it as colour * g + h with g, h >= 0: the strands' colour
  scales what they scatter from the first step, and h carries what does not follow it (the skin).
- `Discriminator`: a convolutional critic with a projection of every label and the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from workers.models.mesogan.config import MesoganConfig
from workers.models.mesogan.volume import integrated_encoding

STRUCTURE_DIMS = 3  # (length, density, curliness), each in [0, 1] over its training range
APPEARANCE_DIMS = 3  # the strands' RGB reflectance from (hue, saturation): hue is circular, colour is not
RADIANCE_CHANNELS = 3  # rho: radiance towards the view per unit irradiance from the light direction
HEAD_CHANNELS = 2 * RADIANCE_CHANNELS  # each as colour * g + h (module docstring)


@dataclass
class FourierBank:
    """Frequencies (K, 2) in cycles per plane unit and phases (K,) of one Fourier-feature map."""

    frequencies: Tensor
    phases: Tensor

    @staticmethod
    def draw(count: int, low: float, high: float, generator: torch.Generator | None, device) -> FourierBank:
        """`count` frequencies with magnitudes uniform in (low, high] and uniform directions and phases."""
        u = torch.rand(count, 3, generator=generator, device="cpu").to(device)
        magnitude = high - (high - low) * u[:, 0]
        angle = 2 * math.pi * u[:, 1]
        frequencies = torch.stack([torch.cos(angle), torch.sin(angle)], -1) * magnitude[:, None]
        return FourierBank(frequencies, 2 * math.pi * u[:, 2])

    def evaluate(self, positions: Tensor) -> Tensor:
        """(K, H, W) features sin(2 pi f . x + phase) at positions (H, W, 2)."""
        angle = 2 * math.pi * positions @ self.frequencies.T + self.phases
        return torch.sin(angle).permute(2, 0, 1)


@dataclass
class PlaneNoise:
    """Everything random about one generated plane besides w: the input map's and each layer's banks."""

    input: FourierBank
    layers: list[FourierBank]


class ModulatedConv(nn.Module):
    """A 3x3 convolution whose weights are scaled per input channel by a style and demodulated (StyleGAN2);
    unpadded, so it trims one texel from each side."""

    def __init__(self, channels_in: int, channels_out: int, w_dims: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.randn(channels_out, channels_in, 3, 3) / math.sqrt(9 * channels_in))
        self.bias = nn.Parameter(torch.zeros(channels_out))
        self.style = nn.Linear(w_dims, channels_in)
        nn.init.ones_(self.style.bias)

    def forward(self, x: Tensor, w: Tensor) -> Tensor:
        b, c, h, wd = x.shape
        s = self.style(w)  # (B, C_in)
        weight = self.weight[None] * s[:, None, :, None, None]
        weight = weight * torch.rsqrt(weight.pow(2).sum(dim=(2, 3, 4), keepdim=True) + 1e-8)
        out = F.conv2d(x.reshape(1, b * c, h, wd), weight.reshape(-1, c, 3, 3), groups=b)
        return out.reshape(b, -1, h - 2, wd - 2) + self.bias[None, :, None, None]


def _unit_rms(x: Tensor) -> Tensor:
    return x * torch.rsqrt(x.pow(2).mean(-1, keepdim=True) + 1e-8)


class Mapping(nn.Module):
    """z and an embedding of the structure parameters, each normalised to unit RMS, to w (the conditional
    mapping of StyleGAN2-ADA): concatenated raw, the three structure values were 3 of 35 inputs beside a
    z of RMS 1, moved the plane by 6% of its spread at initialisation and by nothing after training."""

    def __init__(self, config: MesoganConfig) -> None:
        super().__init__()
        self.latent_dims = config.latent_dims
        self.embed = nn.Linear(STRUCTURE_DIMS, config.latent_dims)
        self.net = config.mapping.build(2 * config.latent_dims, config.w_dims)

    def forward(self, z: Tensor, structure: Tensor) -> Tensor:
        return self.net(torch.cat([_unit_rms(z), _unit_rms(self.embed(structure * 2.0 - 1.0))], -1))


class PlaneGenerator(nn.Module):
    """Synthesis of a window of the infinite tangent feature plane (module docstring)."""

    def __init__(self, config: MesoganConfig) -> None:
        super().__init__()
        self.texel = config.texel
        self.layers = config.generator_layers
        width = config.generator_width
        self.input_features = config.fourier_features
        self.injected = config.injected_features
        nyquist = 0.5 / self.texel
        # Cutoffs rise geometrically from the input band to just below Nyquist (Sec. 6.2.5).
        self.cutoffs = [
            nyquist * config.input_band * (config.top_band / config.input_band) ** (i / max(self.layers, 1))
            for i in range(self.layers + 1)
        ]
        self.inject = config.inject
        self.input = nn.Conv2d(self.input_features, width, 1)
        self.convs = nn.ModuleList(ModulatedConv(width, width, config.w_dims) for _ in range(self.layers))
        self.injections = nn.ModuleList(nn.Conv2d(self.injected, width, 1) for _ in range(self.layers))
        self.output = nn.Conv2d(width, config.plane_channels, 1)

    @property
    def margin(self) -> int:
        """Texels the input window is widened by on each side (one per unpadded 3x3 convolution)."""
        return self.layers

    def draw_noise(self, generator: torch.Generator | None = None, device=None) -> PlaneNoise:
        """The random banks of one plane; `generator` None draws from torch's global stream (training)."""
        device = device or self.output.weight.device
        bank = FourierBank.draw(self.input_features, 0.0, self.cutoffs[0], generator, device)
        layers = [
            FourierBank.draw(self.injected, self.cutoffs[i], self.cutoffs[i + 1], generator, device)
            for i in range(self.layers)
        ]
        return PlaneNoise(bank, layers)

    def positions(self, origin: tuple[int, int], size: tuple[int, int], margin: int, device) -> Tensor:
        """Plane positions (H, W, 2) of texel centres: texel (i, j) of the lattice is at ((i, j) + 1/2) texel,
        `origin` the lattice index of the window's first texel (so windows share exact positions)."""
        rows = torch.arange(
            origin[0] - margin, origin[0] + size[0] + margin, device=device, dtype=torch.float64
        )
        cols = torch.arange(
            origin[1] - margin, origin[1] + size[1] + margin, device=device, dtype=torch.float64
        )
        grid = torch.stack(torch.meshgrid(rows, cols, indexing="ij"), -1)
        return ((grid + 0.5) * self.texel).to(torch.float32)

    def forward(
        self, w: Tensor, noise: list[PlaneNoise], origin: tuple[int, int], size: tuple[int, int]
    ) -> Tensor:
        """Planes (B, C, H, W) of the window of `size` texels at lattice `origin`, one per style and noise."""
        device = w.device
        m = self.margin
        x = torch.stack([n.input.evaluate(self.positions(origin, size, m, device)) for n in noise])
        x = self.input(x)
        for i, conv in enumerate(self.convs):
            x = F.leaky_relu(conv(x, w), 0.2)
            if self.inject:
                inner = self.positions(origin, size, m - i - 1, device)
                fresh = torch.stack([n.layers[i].evaluate(inner) for n in noise])
                x = x + self.injections[i](fresh)
        return self.output(x)


class Decoder(nn.Module):
    """(features, integrated height encoding) -> density, and, with appearance, light and view, radiance."""

    def __init__(self, config: MesoganConfig) -> None:
        super().__init__()
        self.height_frequencies = config.height_frequencies
        hidden = config.decoder.width
        self.trunk = config.decoder.build(config.plane_channels + 2 * config.height_frequencies, hidden + 1)
        self.radiance = config.radiance_head.build(hidden + APPEARANCE_DIMS + 6, HEAD_CHANNELS)

    def density(
        self, features: Tensor, height_mean: Tensor, height_variance: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Extinction (per slab height) and the hidden state the radiance head reads."""
        encoded = integrated_encoding(height_mean, height_variance, self.height_frequencies)
        out = self.trunk(torch.cat([features, encoded], -1))
        # Starts nearly clear (0.4 per slab height): sparse strands over a visible skin, as in most slabs.
        return F.softplus(out[..., 0] - 3.0) * 8.0, out[..., 1:]

    def rho(self, hidden: Tensor, appearance: Tensor, light: Tensor, view: Tensor) -> Tensor:
        """Radiance towards `view` per unit irradiance from `light` (unit directions in the tangent frame,
        z up): the albedo-weighted transport of Eq. 6.4. Zero for light from below the slab."""
        heads = F.softplus(self.radiance(torch.cat([hidden, appearance, light, view], -1)) - 2.0)
        out = appearance * heads[..., :RADIANCE_CHANNELS] + heads[..., RADIANCE_CHANNELS:]
        return out * (light[..., 2:] > 0).to(out.dtype)


class Discriminator(nn.Module):
    """Strided convolutions to a feature vector; logit = linear(f) + <f, embed(labels)> (projection)."""

    def __init__(self, config: MesoganConfig) -> None:
        super().__init__()
        width = config.discriminator_width
        layers: list[nn.Module] = [nn.Conv2d(3, width, 3, padding=1), nn.LeakyReLU(0.2)]
        size = config.image_size
        while size > 4:
            layers += [nn.Conv2d(width, width, 4, stride=2, padding=1), nn.LeakyReLU(0.2)]
            size //= 2
        self.features = nn.Sequential(
            *layers, nn.Flatten(), nn.Linear(width * size * size, width), nn.LeakyReLU(0.2)
        )
        self.out = nn.Linear(width, 1)
        self.embed = nn.Linear(LABEL_DIMS, width)

    def forward(self, image: Tensor, labels: Tensor) -> Tensor:
        f = self.features(image * 2.0 - 1.0)
        return self.out(f)[:, 0] + (f * self.embed(labels)).sum(-1) / math.sqrt(f.shape[-1])


LABEL_DIMS = STRUCTURE_DIMS + APPEARANCE_DIMS + 3 + 3  # + light direction + camera position


class MesoGAN(nn.Module):
    """The trained parts together; `generator_parameters` are what the generator phase moves."""

    def __init__(self, config: MesoganConfig) -> None:
        super().__init__()
        self.config = config
        self.mapping = Mapping(config)
        self.synthesis = PlaneGenerator(config)
        self.decoder = Decoder(config)
        self.discriminator = Discriminator(config)

    def generator_parameters(self) -> list[nn.Parameter]:
        return [*self.mapping.parameters(), *self.synthesis.parameters(), *self.decoder.parameters()]
