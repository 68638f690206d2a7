"""Scene content made from parameters: procedural meshes (`procedural`, `mesoscale`, named in `catalogue`),
environment maps (`envmaps`) and the built-in scenes (`builtin`). Above `importers`, whose image readers the
environment maps use."""
