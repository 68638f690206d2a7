"""Scenes, meshes and images made by other tools: glTF (`gltf`), USD (`usd`), mesh files (`meshio`), EXR and
PNG images (`image_io`) and material textures (`textures`). Above `geometry`, whose `MeshData` they build."""
