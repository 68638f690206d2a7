"""The scene format: what a scene is (`spec`), what its variables mean (`variables`), and the error that
names a scene's field at fault (`errors`). The bottom layer of `workers.scene`: it imports no other."""
