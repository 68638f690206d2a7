"""Scene geometry: the triangle mesh (`mesh`, a leaf), checked meshes of shapes (`shapes`), the triangle
budget a scene is held to (`budget`), a scene flattened into world-space triangles (`compile`,
`variable_scene`) and a default camera for a box (`framing`). Above `format`; the importers and generators
that build shapes from files and parameters sit above it, so `registry` names them by shape type and they
are imported on first use."""
