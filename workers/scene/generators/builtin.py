"""Built-in scenes: functions returning a SceneSpec, addressed by name (``nbake render cornell_box``)."""

from __future__ import annotations

from collections.abc import Callable

from workers.scene.format.errors import SceneError
from workers.scene.format.spec import AlbedoVariable as _Albedo
from workers.scene.format.spec import (
    BoxShape,
    Camera,
    Conductor,
    ConstantBackground,
    Dielectric,
    Diffuse,
    DirectionalLight,
    EnvironmentMap,
    Plastic,
    PointLight,
    ProceduralShape,
    RectangleShape,
    SceneObject,
    SceneSpec,
    SphereShape,
    Transform,
)
from workers.scene.format.spec import LightIntensityVariable as _LightIntensity
from workers.scene.format.spec import LightPositionVariable as _LightPosition
from workers.scene.format.spec import RoughnessVariable as _Roughness
from workers.scene.format.spec import TranslateVariable as _Translate
from workers.scene.generators.envmaps import sun_direction

BUILTIN_SCENES: dict[str, Callable[[], SceneSpec]] = {}


def builtin(fn: Callable[[], SceneSpec]) -> Callable[[], SceneSpec]:
    BUILTIN_SCENES[fn.__name__] = fn
    return fn


def get_builtin(name: str) -> SceneSpec:
    if name not in BUILTIN_SCENES:
        raise SceneError(
            "scene", f"unknown built-in scene {name!r}; known: {', '.join(sorted(BUILTIN_SCENES))}"
        )
    return BUILTIN_SCENES[name]()


CORNELL_WHITE = (0.885809, 0.698859, 0.666422)
CORNELL_RED = (0.570068, 0.0430135, 0.0443706)
CORNELL_GREEN = (0.105421, 0.37798, 0.076425)
CORNELL_LIGHT = (18.387, 13.9873, 6.75357)


def cornell_walls() -> list[SceneObject]:
    """The room of Mitsuba 3's `cornell_box()`: same rectangles, transforms and light."""
    return [
        SceneObject(
            name="floor",
            shape=RectangleShape(),
            material="white",
            transform=Transform(translate=(0, -1, 0), rotate=(-90, 0, 0)),
        ),
        SceneObject(
            name="ceiling",
            shape=RectangleShape(),
            material="white",
            transform=Transform(translate=(0, 1, 0), rotate=(90, 0, 0)),
        ),
        SceneObject(
            name="back", shape=RectangleShape(), material="white", transform=Transform(translate=(0, 0, -1))
        ),
        SceneObject(
            name="green_wall",
            shape=RectangleShape(),
            material="green",
            transform=Transform(translate=(1, 0, 0), rotate=(0, -90, 0)),
        ),
        SceneObject(
            name="red_wall",
            shape=RectangleShape(),
            material="red",
            transform=Transform(translate=(-1, 0, 0), rotate=(0, 90, 0)),
        ),
        SceneObject(
            name="light",
            shape=RectangleShape(),
            material="white",
            emission=CORNELL_LIGHT,
            transform=Transform(translate=(0, 0.99, 0.01), rotate=(90, 0, 0), scale=(0.23, 0.19, 0.19)),
        ),
    ]


def cornell_materials() -> dict:
    return {
        "white": Diffuse(reflectance=CORNELL_WHITE),
        "red": Diffuse(reflectance=CORNELL_RED),
        "green": Diffuse(reflectance=CORNELL_GREEN),
    }


CORNELL_CAMERA = Camera(
    position=(0, 0, 3.9), target=(0, 0, 0), up=(0, 1, 0), fov=39.3077, width=256, height=256
)


@builtin
def cornell_box() -> SceneSpec:
    """Identical to `mitsuba.cornell_box()` (geometry, reflectances, light, camera)."""
    boxes = [
        SceneObject(
            name="small_box",
            shape=BoxShape(),
            material="white",
            transform=Transform(translate=(0.335, -0.7, 0.38), rotate=(0, -17, 0), scale=0.3),
        ),
        SceneObject(
            name="large_box",
            shape=BoxShape(),
            material="white",
            transform=Transform(translate=(-0.33, -0.4, -0.28), rotate=(0, 18.25, 0), scale=(0.3, 0.61, 0.3)),
        ),
    ]
    return SceneSpec(
        name="cornell_box",
        materials=cornell_materials(),
        objects=cornell_walls() + boxes,
        camera=CORNELL_CAMERA,
    )


@builtin
def cornell_glossy() -> SceneSpec:
    """The Cornell room with a rough gold-like sphere and a smooth glass sphere: glossy light and caustics."""
    spheres = [
        SceneObject(
            name="metal_sphere",
            shape=SphereShape(radius=0.3, subdivisions=6),
            material="metal",
            transform=Transform(translate=(-0.38, -0.7, -0.3)),
        ),
        SceneObject(
            name="glass_sphere",
            shape=SphereShape(radius=0.3, subdivisions=6),
            material="glass",
            transform=Transform(translate=(0.38, -0.7, 0.25)),
        ),
    ]
    materials = cornell_materials() | {
        "metal": Conductor(roughness=0.15, specular=(0.95, 0.78, 0.45)),
        "glass": Dielectric(ior=1.5, roughness=0.0),
    }
    return SceneSpec(
        name="cornell_glossy", materials=materials, objects=cornell_walls() + spheres, camera=CORNELL_CAMERA
    )


def ground(size: float, material: str = "ground") -> SceneObject:
    """A square floor of side `size` in the y = 0 plane facing up."""
    return SceneObject(
        name="ground",
        shape=ProceduralShape(generator="ground_plane", params={"size": size}),
        material=material,
    )


@builtin
def dense_foliage() -> SceneSpec:
    """A fractal tree with ~26k thin leaves on a ground plane, lit by a directional sun and a sky.

    The sky's own sun disc is switched off (`sun_irradiance: 0`) so that the directional
    light, placed where the sky draws its sun glow, carries the sun's energy exactly once.
    """
    tree = {"seed": 7}
    sun_elevation, sun_azimuth = 40.0, 30.0
    toward_sun = sun_direction(sun_elevation, sun_azimuth)
    return SceneSpec(
        name="dense_foliage",
        materials={
            "ground": Diffuse(reflectance=(0.3, 0.26, 0.18)),
            "bark": Diffuse(reflectance=(0.25, 0.17, 0.1)),
            "leaves": Diffuse(reflectance=(0.18, 0.42, 0.08)),
        },
        objects=[
            ground(60.0),
            SceneObject(
                name="branches",
                shape=ProceduralShape(generator="fractal_tree", params=tree | {"parts": "branches"}),
                material="bark",
            ),
            SceneObject(
                name="leaves",
                shape=ProceduralShape(generator="fractal_tree", params=tree | {"parts": "leaves"}),
                material="leaves",
            ),
        ],
        lights=[DirectionalLight(direction=tuple(-toward_sun), irradiance=(3.0, 2.8, 2.5))],
        environment=EnvironmentMap(
            procedural="sky",
            params={"sun_elevation": sun_elevation, "sun_azimuth": sun_azimuth, "sun_irradiance": 0.0},
        ),
        camera=Camera(position=(0.0, 1.7, 6.2), target=(0.0, 1.55, 0.0), fov=40.0, width=256, height=256),
    )


@builtin
def high_poly() -> SceneSpec:
    """A ~1M-triangle noise-displaced sphere in glossy plastic under a seeded studio environment."""
    return SceneSpec(
        name="high_poly",
        materials={"clay": Plastic(diffuse=(0.55, 0.3, 0.2), roughness=0.15)},
        objects=[
            SceneObject(
                name="displaced_sphere",
                shape=ProceduralShape(generator="displaced_sphere", params={"seed": 1}),
                material="clay",
            )
        ],
        environment=EnvironmentMap(procedural="studio", params={"seed": 1}),
        camera=Camera(position=(0.0, 1.2, 4.0), target=(0.0, 0.0, 0.0), fov=40.0, width=256, height=256),
    )


@builtin
def fur_patch() -> SceneSpec:
    """4000 curved thin strands (~96k triangles) on a square base, lit by a point and a small area light."""
    return SceneSpec(
        name="fur_patch",
        materials={
            "fur": Diffuse(reflectance=(0.62, 0.45, 0.3)),
            "white": Diffuse(reflectance=(0.8, 0.8, 0.8)),
        },
        objects=[
            SceneObject(
                name="fur", shape=ProceduralShape(generator="fur", params={"seed": 3}), material="fur"
            ),
            SceneObject(
                name="area_light",
                shape=RectangleShape(),
                material="white",
                emission=(16.0, 15.0, 13.0),
                transform=Transform(translate=(-0.6, 1.2, 0.2), rotate=(90, 0, 0), scale=0.25),
            ),
        ],
        lights=[PointLight(position=(0.7, 1.0, 0.8), intensity=(2.5, 2.6, 3.0))],
        camera=Camera(position=(0.0, 0.5, 0.95), target=(0.0, 0.0, 0.0), fov=40.0, width=256, height=256),
    )


@builtin
def fur_ball() -> SceneSpec:
    """A UV-mapped ball whose material `fur` a mesoscale material (`mesogan`) covers, on a floor it casts
    its shadow on, under a sun and a grey sky: small enough to path-trace with its real strands."""
    return SceneSpec(
        name="fur_ball",
        materials={
            "fur": Diffuse(reflectance=(0.5, 0.2, 0.1)),
            "floor": Diffuse(reflectance=(0.45, 0.45, 0.4)),
        },
        objects=[
            SceneObject(
                name="ball",
                shape=SphereShape(center=(0.0, 0.5, 0.0), radius=0.5, subdivisions=3),
                material="fur",
            ),
            ground(6.0, "floor"),
        ],
        lights=[DirectionalLight(direction=(-0.4, -1.0, -0.5), irradiance=(3.0, 3.0, 3.0))],
        environment=ConstantBackground(radiance=(0.3, 0.3, 0.3)),
        camera=Camera(position=(0.0, 1.4, 3.0), target=(0.0, 0.45, 0.0), fov=40.0, width=128, height=128),
    )


@builtin
def env_lit_objects() -> SceneSpec:
    """Glossy, plastic and diffuse spheres and boxes on a ground plane under the `courtyard` HDRI."""

    def sphere(name: str, material: str, x: float, z: float, r: float) -> SceneObject:
        return SceneObject(
            name=name,
            shape=SphereShape(radius=r, subdivisions=5),
            material=material,
            transform=Transform(translate=(x, r, z)),
        )

    def cube(name: str, material: str, x: float, z: float, half: float, turn: float) -> SceneObject:
        return SceneObject(
            name=name,
            shape=BoxShape(),
            material=material,
            transform=Transform(translate=(x, half, z), rotate=(0, turn, 0), scale=half),
        )

    return SceneSpec(
        name="env_lit_objects",
        materials={
            "ground": Diffuse(reflectance=(0.45, 0.45, 0.45)),
            "chrome": Conductor(roughness=0.03, specular=(0.95, 0.95, 0.95)),
            "red_plastic": Plastic(diffuse=(0.7, 0.08, 0.06), roughness=0.2),
            "blue_diffuse": Diffuse(reflectance=(0.15, 0.3, 0.7)),
            "rough_copper": Conductor(roughness=0.3, specular=(0.95, 0.64, 0.54)),
        },
        objects=[
            ground(30.0),
            sphere("chrome_sphere", "chrome", -1.2, 0.0, 0.5),
            sphere("plastic_sphere", "red_plastic", 0.0, 0.5, 0.5),
            sphere("small_copper_sphere", "rough_copper", 0.6, 1.3, 0.25),
            cube("diffuse_box", "blue_diffuse", 1.25, -0.2, 0.4, 25.0),
            cube("copper_box", "rough_copper", -0.2, -0.9, 0.3, -15.0),
        ],
        environment=EnvironmentMap(builtin="courtyard"),
        camera=Camera(position=(0.0, 1.7, 5.8), target=(0.0, 0.4, 0.0), fov=40.0, width=256, height=256),
    )


def sun_and_sky(
    elevation: float, azimuth: float, irradiance=(3.0, 2.8, 2.5)
) -> tuple[list[DirectionalLight], EnvironmentMap]:
    """A directional sun and a procedural sky whose own sun disc is off, as in `dense_foliage`."""
    toward_sun = sun_direction(elevation, azimuth)
    sky = EnvironmentMap(
        procedural="sky", params={"sun_elevation": elevation, "sun_azimuth": azimuth, "sun_irradiance": 0.0}
    )
    return [DirectionalLight(direction=tuple(-toward_sun), irradiance=irradiance)], sky


@builtin
def menger_sponge() -> SceneSpec:
    """A level-3 Menger sponge (36k triangles, closed, holes at every scale) on a ground plane, sun and sky.

    A test asset for neural levels of detail: its visibility through the holes changes with scale.
    """
    lights, sky = sun_and_sky(45.0, 120.0)
    return SceneSpec(
        name="menger_sponge",
        materials={
            "ground": Diffuse(reflectance=(0.3, 0.26, 0.18)),
            "sponge": Diffuse(reflectance=(0.7, 0.7, 0.7)),
        },
        objects=[
            ground(20.0),
            SceneObject(
                name="sponge",
                shape=ProceduralShape(generator="menger_sponge", params={"level": 3, "size": 1.0}),
                material="sponge",
            ),
        ],
        lights=lights,
        environment=sky,
        camera=Camera(position=(1.5, 1.4, 2.1), target=(0.0, 0.45, 0.0), fov=40.0, width=256, height=256),
    )


@builtin
def thin_walls() -> SceneSpec:
    """A 3 x 3-room, two-storey shell of thin walls (1/100 of its size) with windows, on a ground plane.

    A test asset for neural levels of detail: thin closed walls must stay opaque when prefiltered.
    """
    lights, sky = sun_and_sky(35.0, 160.0)
    return SceneSpec(
        name="thin_walls",
        materials={
            "ground": Diffuse(reflectance=(0.3, 0.26, 0.18)),
            "walls": Diffuse(reflectance=(0.75, 0.72, 0.68)),
        },
        objects=[
            ground(30.0),
            SceneObject(
                name="rooms",
                shape=ProceduralShape(generator="thin_wall_rooms", params={"seed": 0}),
                material="walls",
            ),
        ],
        lights=lights,
        environment=sky,
        camera=Camera(position=(2.6, 2.2, 3.4), target=(0.0, 0.4, 0.0), fov=40.0, width=256, height=256),
    )


@builtin
def closed_box() -> SceneSpec:
    """Inside a sealed thin-walled box under a strong constant environment: the correct image is black.

    The light-leak test of Weier et al. (Fig. 10): the camera looks at the inner back wall, corners
    and edges in view; any light in the image leaked through the 0.02-thick walls.
    """
    return SceneSpec(
        name="closed_box",
        materials={"box": Diffuse(reflectance=(0.8, 0.8, 0.8))},
        objects=[
            SceneObject(
                name="box",
                shape=ProceduralShape(generator="hollow_box", params={"size": 2.0, "thickness": 0.02}),
                material="box",
            )
        ],
        environment=ConstantBackground(radiance=(6.0, 4.0, 2.0)),
        camera=Camera(position=(0.0, 1.0, 0.9), target=(0.0, 1.0, -1.0), fov=70.0, width=256, height=256),
    )


@builtin
def glossy_row() -> SceneSpec:
    """Glossy objects facing each other on a glossy floor before a glossy back panel, under the `studio`
    HDRI: strong glossy interreflections (the `prt` kind's second scene; indirect light is most of what
    the panel and the floor show between the objects)."""

    def sphere(name: str, material: str, x: float, z: float, r: float) -> SceneObject:
        return SceneObject(
            name=name,
            shape=SphereShape(radius=r, subdivisions=4),
            material=material,
            transform=Transform(translate=(x, r, z)),
        )

    return SceneSpec(
        name="glossy_row",
        materials={
            "floor": Conductor(roughness=0.15, specular=(0.8, 0.8, 0.82)),
            "panel": Plastic(diffuse=(0.85, 0.82, 0.75), roughness=0.08),
            "gold": Conductor(roughness=0.1, specular=(1.0, 0.78, 0.34)),
            "copper": Conductor(roughness=0.25, specular=(0.95, 0.64, 0.54)),
            "red_plastic": Plastic(diffuse=(0.75, 0.1, 0.08), roughness=0.05),
            "white_diffuse": Diffuse(reflectance=(0.8, 0.8, 0.8)),
        },
        objects=[
            SceneObject(
                name="floor",
                shape=RectangleShape(),
                material="floor",
                transform=Transform(rotate=(-90.0, 0.0, 0.0), scale=2.0),
            ),
            SceneObject(
                name="panel",
                shape=RectangleShape(),
                material="panel",
                transform=Transform(translate=(0.0, 0.8, -1.2), scale=(2.0, 0.8, 1.0)),
            ),
            sphere("gold_sphere", "gold", -0.9, -0.2, 0.35),
            sphere("red_sphere", "red_plastic", 0.0, 0.1, 0.35),
            sphere("copper_sphere", "copper", 0.9, -0.2, 0.35),
            SceneObject(
                name="white_box",
                shape=BoxShape(),
                material="white_diffuse",
                transform=Transform(translate=(0.0, 0.25, -0.7), rotate=(0.0, 30.0, 0.0), scale=0.25),
            ),
        ],
        environment=EnvironmentMap(builtin="studio"),
        camera=Camera(position=(0.0, 1.2, 3.2), target=(0.0, 0.3, 0.0), fov=40.0, width=256, height=256),
    )


@builtin
def cornell_variable() -> SceneSpec:
    """A variable Cornell box of 11 dimensions (thesis Sec. 5.6, SPHERE CAUSTIC-like): both wall colours,
    the ceiling light's x and z, the small box's x and z and a metal sphere's roughness."""
    sphere = SceneObject(
        name="sphere",
        shape=SphereShape(radius=0.25, subdivisions=4),
        material="metal",
        transform=Transform(translate=(-0.35, -0.75, 0.2)),
    )
    base = cornell_box()
    materials = dict(base.materials) | {"metal": Conductor(roughness=0.2, specular=(0.95, 0.9, 0.8))}
    variables = [
        _Albedo(name="red_wall", material="red", min=(0.2, 0.02, 0.02), max=(0.9, 0.4, 0.3)),
        _Albedo(name="green_wall", material="green", min=(0.02, 0.2, 0.02), max=(0.3, 0.8, 0.4)),
        _LightPosition(name="light", light="light", min=(-0.5, 0.0, -0.5), max=(0.5, 0.0, 0.5)),
        _Translate(name="box", object="small_box", min=(-0.25, 0.0, -0.3), max=(0.2, 0.0, 0.25)),
        _Roughness(name="sphere_roughness", material="metal", min=0.02, max=0.5),
    ]
    return SceneSpec(
        name="cornell_variable",
        materials=materials,
        objects=[*base.objects, sphere],
        camera=base.camera,
        variables=variables,
    )


@builtin
def mirror_variable() -> SceneSpec:
    """A box moving in front of a mirror in a Cornell room, seen at an angle (thesis Fig. 5.6): glossy
    reflections and shadows of a moving object, and the light's x; 3 dimensions.

    The mirror shows the room's open front: a third of the window centres SSIM weighs in `bench_explore`'s
    32^2 frames, dark but for what the mirror's GGX tail (alpha 0.01) reflects of the lit room, 1-5
    thousandths of linear radiance, strongest around the light's reflection. sRGB magnifies errors there
    (12.92x below 0.0031): networks that learned the reflection had most of their DSSIM there (the bench's
    error maps, explore25), and G-buffers that follow the mirror must keep the mirror where its
    reflection escapes, so the network can learn that glow (`gbuffer._through_mirrors`, explore26)."""
    walls = [o for o in cornell_walls() if o.name != "back"]
    mirror = SceneObject(
        name="mirror",
        shape=RectangleShape(),
        material="mirror",
        transform=Transform(translate=(0, 0, -1)),
    )
    box = SceneObject(
        name="box",
        shape=BoxShape(),
        material="white",
        transform=Transform(translate=(0.0, -0.8, -0.2), rotate=(0, 25, 0), scale=0.2),
    )
    materials = cornell_materials() | {"mirror": Conductor(roughness=0.01, specular=(0.9, 0.9, 0.9))}
    return SceneSpec(
        name="mirror_variable",
        materials=materials,
        objects=[*walls, mirror, box],
        camera=Camera(position=(0.6, 0.1, 3.6), target=(-0.2, -0.3, -1.0), fov=39.3, width=256, height=256),
        variables=[
            _Translate(name="box", object="box", min=(-0.6, 0.0, -0.6), max=(0.6, 0.0, 0.4)),
            _LightPosition(name="light", light="light", min=(-0.5, 0.0, 0.0), max=(0.5, 0.0, 0.0)),
        ],
    )


@builtin
def mirror_room_variable() -> SceneSpec:
    """`mirror_variable` as a configurator would vary it, 8 dimensions: the box's x and z, the light's x
    and z and intensity, and the red wall's colour. The thesis's gain over uniform sampling grows with
    the dimensions (Fig. 5.15): with `EXPLORE_BENCH_SCENES=mirror_room_variable`, `bench_explore` put
    active over uniform at DSSIM 1.01 / 1.06 here against 1.22 / 1.15 on `mirror_variable` (seeds 3 / 4,
    300 CPU s, explore24)."""
    variables = [
        _Translate(name="box", object="box", min=(-0.6, 0.0, -0.6), max=(0.6, 0.0, 0.4)),
        _LightPosition(name="light", light="light", min=(-0.5, 0.0, -0.5), max=(0.5, 0.0, 0.5)),
        _LightIntensity(name="light_intensity", light="light", min=0.5, max=1.5),
        _Albedo(name="red_wall", material="red", min=(0.2, 0.02, 0.02), max=(0.9, 0.4, 0.3)),
    ]
    base = mirror_variable().model_dump()
    return SceneSpec.model_validate(base | {"name": "mirror_room_variable", "variables": variables})


@builtin
def cornell_moving_light() -> SceneSpec:
    """The Cornell box with its ceiling light moving in x and z: the smallest variable scene (2
    dimensions), where moving shadows and colour bleeding change with the light."""
    base = cornell_box()
    light = _LightPosition(name="light", light="light", min=(-0.5, 0.0, -0.5), max=(0.5, 0.0, 0.5))
    return SceneSpec.model_validate(
        base.model_dump() | {"name": "cornell_moving_light", "variables": [light]}
    )
