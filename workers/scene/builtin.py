"""Built-in scenes: functions returning a SceneSpec, addressed by name (``nbake render cornell_box``)."""

from __future__ import annotations

from collections.abc import Callable

from workers.scene.spec import (
    BoxShape,
    Camera,
    Diffuse,
    RectangleShape,
    SceneObject,
    SceneSpec,
    Transform,
)

BUILTIN_SCENES: dict[str, Callable[[], SceneSpec]] = {}


def builtin(fn: Callable[[], SceneSpec]) -> Callable[[], SceneSpec]:
    BUILTIN_SCENES[fn.__name__] = fn
    return fn


def get_builtin(name: str) -> SceneSpec:
    from workers.scene.errors import SceneError

    if name not in BUILTIN_SCENES:
        raise SceneError("scene", f"unknown built-in scene {name!r}; known: {', '.join(sorted(BUILTIN_SCENES))}")
    return BUILTIN_SCENES[name]()


CORNELL_WHITE = (0.885809, 0.698859, 0.666422)
CORNELL_RED = (0.570068, 0.0430135, 0.0443706)
CORNELL_GREEN = (0.105421, 0.37798, 0.076425)
CORNELL_LIGHT = (18.387, 13.9873, 6.75357)


def cornell_walls() -> list[SceneObject]:
    """The room of Mitsuba 3's `cornell_box()`: same rectangles, transforms and light."""
    return [
        SceneObject(name="floor", shape=RectangleShape(), material="white",
                    transform=Transform(translate=(0, -1, 0), rotate=(-90, 0, 0))),
        SceneObject(name="ceiling", shape=RectangleShape(), material="white",
                    transform=Transform(translate=(0, 1, 0), rotate=(90, 0, 0))),
        SceneObject(name="back", shape=RectangleShape(), material="white",
                    transform=Transform(translate=(0, 0, -1))),
        SceneObject(name="green_wall", shape=RectangleShape(), material="green",
                    transform=Transform(translate=(1, 0, 0), rotate=(0, -90, 0))),
        SceneObject(name="red_wall", shape=RectangleShape(), material="red",
                    transform=Transform(translate=(-1, 0, 0), rotate=(0, 90, 0))),
        SceneObject(name="light", shape=RectangleShape(), material="white", emission=CORNELL_LIGHT,
                    transform=Transform(translate=(0, 0.99, 0.01), rotate=(90, 0, 0), scale=(0.23, 0.19, 0.19))),
    ]


def cornell_materials() -> dict:
    return {
        "white": Diffuse(reflectance=CORNELL_WHITE),
        "red": Diffuse(reflectance=CORNELL_RED),
        "green": Diffuse(reflectance=CORNELL_GREEN),
    }


CORNELL_CAMERA = Camera(position=(0, 0, 3.9), target=(0, 0, 0), up=(0, 1, 0), fov=39.3077, width=256, height=256)


@builtin
def cornell_box() -> SceneSpec:
    """Identical to `mitsuba.cornell_box()` (geometry, reflectances, light, camera)."""
    boxes = [
        SceneObject(name="small_box", shape=BoxShape(), material="white",
                    transform=Transform(translate=(0.335, -0.7, 0.38), rotate=(0, -17, 0), scale=0.3)),
        SceneObject(name="large_box", shape=BoxShape(), material="white",
                    transform=Transform(translate=(-0.33, -0.4, -0.28), rotate=(0, 18.25, 0), scale=(0.3, 0.61, 0.3))),
    ]
    return SceneSpec(name="cornell_box", materials=cornell_materials(), objects=cornell_walls() + boxes,
                     camera=CORNELL_CAMERA)
