"""Writing USD stages for tests with usd-core: meshes, transforms, UsdPreviewSurface materials with
UsdUVTexture inputs, UsdLux lights and cameras."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt


def new_stage(path, up: str = "Y") -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.Xform.Define(stage, "/World")
    return stage


def place(prim, matrix: np.ndarray) -> None:
    """Our column-vector 4x4 `matrix` as the prim's one transform op (USD's matrices act on row vectors)."""
    UsdGeom.Xformable(prim).AddTransformOp().Set(Gf.Matrix4d(np.asarray(matrix, float).T.tolist()))


def mesh(stage, path: str, positions, triangles, *, normals=None, uvs=None, matrix=None, material=None):
    """A triangle mesh; `uvs` in our (and glTF's) convention, v down the image, stored as USD's st."""
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(positions, np.float32)))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(triangles)))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray(np.asarray(triangles).ravel().tolist()))
    if normals is not None:
        m.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(normals, np.float32)))
        m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    if uvs is not None:
        st = np.asarray(uvs, np.float32).copy()
        st[:, 1] = 1.0 - st[:, 1]
        primvar = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, "vertex")
        primvar.Set(Vt.Vec2fArray.FromNumpy(st))
    if matrix is not None:
        place(m.GetPrim(), matrix)
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
    return m


def preview_surface(stage, path: str, texture: str | None = None, **inputs) -> UsdShade.Material:
    """A UsdPreviewSurface material; `texture` (a file) feeds diffuseColor through a UsdUVTexture."""
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    types = {"diffuseColor": Sdf.ValueTypeNames.Color3f, "emissiveColor": Sdf.ValueTypeNames.Color3f}
    for name, value in inputs.items():
        shader.CreateInput(name, types.get(name, Sdf.ValueTypeNames.Float)).Set(
            Gf.Vec3f(*value) if name in types else float(value)
        )
    if texture is not None:
        reader = UsdShade.Shader.Define(stage, f"{path}/St")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
        tex = UsdShade.Shader.Define(stage, f"{path}/Texture")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(texture)
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def camera(stage, path: str, matrix: np.ndarray, fov_degrees: float) -> None:
    cam = UsdGeom.Camera.Define(stage, path)
    aperture = 20.955
    cam.CreateVerticalApertureAttr(aperture)
    cam.CreateHorizontalApertureAttr(aperture)
    cam.CreateFocalLengthAttr(aperture / (2.0 * np.tan(np.radians(fov_degrees) / 2)))
    place(cam.GetPrim(), matrix)


def point_light(stage, path: str, position, intensity: float) -> None:
    light = UsdLux.SphereLight.Define(stage, path)
    light.CreateRadiusAttr(0.0)
    light.CreateIntensityAttr(intensity)
    matrix = np.eye(4)
    matrix[:3, 3] = position
    place(light.GetPrim(), matrix)


def usdc(usda: bytes) -> bytes:
    """The stage written as text `usda`, in USD's binary crate format (what a `.usdc` file holds)."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.ImportFromString(usda.decode())
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "stage.usdc"
        layer.Export(str(path))
        return path.read_bytes()
