"""Scenes: what a scene is, and everything that turns one into triangles and images. Five layers, each
importing only those below it (the `scene:` contract of `[tool.importlinter]` in pyproject.toml):

- `format`: the scene description (`spec`), its variables and the error that names a field;
- `geometry`: meshes, shapes built by type (`registry`), the triangle budget, the world-space triangles
  (`compile`);
- `importers`: glTF, USD, mesh files, EXR/PNG images and material textures;
- `generators`: procedural meshes, environment maps and the built-in scenes;
- `portability`: scene files (`io`), the reference a job carries (`reference`), its stored files, the scene
  an artifact keeps (`portable`).
"""
