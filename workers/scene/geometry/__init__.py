"""Scene geometry: checked triangle meshes (`shapes`), the triangle budget a scene is held to (`budget`),
and a scene flattened into world-space triangles (`compile`, `variable_scene`). Above `format`; it names the
importers and generators that build shapes by type and imports them on first use (`shapes`)."""
