"""The report's path-traced view: its curve times frames, not the first render's start-up."""

from __future__ import annotations

from dataclasses import replace
from itertools import chain, repeat

import numpy as np

from workers.render import render as render_module
from workers.render.render import RenderSettings
from workers.runtime import view as view_module
from workers.runtime.view import PathTracedView
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene


def test_the_curve_warms_up_once_untimed_and_keeps_its_frames_exact(monkeypatch):
    rendered: list[int] = []

    def counting_render(tracer, settings, **kwargs):
        rendered.append(settings.spp)
        return render_module.render(tracer, settings, **kwargs)

    monkeypatch.setattr(view_module, "render", counting_render)
    settings = RenderSettings(spp=1, width=12, height=12, max_depth=3, seed=4, threads=1)
    view = PathTracedView(compile_scene(get_builtin("cornell_glossy")), settings, reference_spp=32)
    curve = view.curve()

    assert rendered == [1, 1, 4, 16]  # one untimed warm-up render before the first timed frame
    assert [frame.label for frame in curve] == ["1 spp", "4 spp", "16 spp"]
    view.frame(4)
    assert rendered == [1, 1, 4, 16]  # frames are kept, the warm-up is not repeated
    direct = render_module.render(view.tracer, settings.model_copy(update={"spp": 16})).image
    np.testing.assert_array_equal(curve[-1].image, direct)


def test_a_frame_asked_for_several_renders_is_timed_by_their_median_and_kept(monkeypatch):
    times = chain([9.0, 1.0, 3.0, 2.0], repeat(100.0))  # the warm-up's, the 16-spp renders', any later

    def timed_render(tracer, settings, **kwargs):
        result = render_module.render(tracer, settings, **kwargs)
        return replace(result, seconds=next(times))

    monkeypatch.setattr(view_module, "render", timed_render)
    settings = RenderSettings(spp=1, width=8, height=8, max_depth=3, seed=4, threads=1)
    view = PathTracedView(compile_scene(get_builtin("cornell_glossy")), settings, reference_spp=32)

    assert view.frame(16).seconds == 1.0
    three = view.frame(16, renders=3)
    assert three.seconds == 2.0  # the median of 1, 3 and 2
    assert view.frame(16).seconds == 2.0 and view.curve()[-1].seconds == 2.0  # the curve keeps it
    np.testing.assert_array_equal(three.image, view.frame(16).image)
