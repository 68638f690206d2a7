"""The view a report measures a model on, and plain path tracing of it: the curve, the converged reference.

Renders are kept by their settings, so a kind that needs a path-traced frame of the view for its own
figures (the reference at its resolution, Embree at the model's spp and seed) gets the one the report
uses instead of tracing it twice.
"""

from __future__ import annotations

import os
import statistics
from dataclasses import dataclass, field

import numpy as np

from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.runtime.report import PATH_TRACING_SPP, TimedImage
from workers.scene.geometry.compile import CompiledScene

REFERENCE_SEED_OFFSET = 2  # the reference's noise is independent of every frame rendered at the view's seed


@dataclass
class PathTracedView:
    """Path tracing of one view (`settings` without its spp) of the full scene, rendered on demand once."""

    scene: CompiledScene
    settings: RenderSettings
    reference_spp: int
    tracer: PathTracer | None = field(default=None, repr=False)  # built on first use when not given
    _images: dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _seconds: dict[int, list[float]] = field(default_factory=dict, repr=False)  # every render's, per spp
    _rays: dict[int, int] = field(default_factory=dict, repr=False)
    _reference: np.ndarray | None = field(default=None, repr=False)
    _warm: bool = field(default=False, repr=False)

    def _path_tracer(self) -> PathTracer:
        if self.tracer is None:
            self.tracer = PathTracer(self.scene)
        return self.tracer

    def at(self, spp: int) -> RenderSettings:
        """The view's settings at `spp`."""
        return self.settings.model_copy(update={"spp": spp})

    def frame(self, spp: int, renders: int = 1) -> TimedImage:
        """The view path-traced at `spp` with the view's seed, timed: the median of at least `renders`
        renders (the image is the same each time), as many as any call asked for."""
        seconds = self._seconds.setdefault(spp, [])
        while len(seconds) < renders:
            if not self._warm:  # kernels load and threads start on a first render: not the frame's time
                render(self._path_tracer(), self.at(1))
                self._warm = True
            result = render(self._path_tracer(), self.at(spp))
            self._images.setdefault(spp, result.image)
            self._rays.setdefault(spp, result.rays_traced)
            seconds.append(result.seconds)
        return TimedImage(f"{spp} spp", self._images[spp], statistics.median(seconds))

    def rays(self, spp: int) -> int:
        """The rays the view's frame at `spp` traced: its cost counted, the same on every machine and load."""
        self.frame(spp)
        return self._rays[spp]

    def curve_spp(self) -> list[int]:
        """The curve's sample counts: `PATH_TRACING_SPP` below the reference's spp."""
        return [spp for spp in PATH_TRACING_SPP if spp < self.reference_spp]

    def curve(self) -> list[TimedImage]:
        """The report's speed-against-error curve, at `curve_spp`."""
        return [self.frame(spp) for spp in self.curve_spp()]

    def reference(self) -> np.ndarray:
        """The converged image every frame is measured against (its own seed)."""
        if self._reference is None:
            settings = self.at(self.reference_spp).model_copy(
                # the image is the same on any number of threads; its time is not measured
                update={"seed": self.settings.seed + REFERENCE_SEED_OFFSET, "threads": os.cpu_count() or 1}
            )
            self._reference = render(self._path_tracer(), settings).image
        return self._reference
