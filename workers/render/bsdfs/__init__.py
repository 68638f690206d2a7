"""The built-in BSDF families, one module each; importing this package registers them by name."""

from workers.render.bsdfs import conductor, dielectric, diffuse, pbr, plastic

__all__ = ["conductor", "dielectric", "diffuse", "pbr", "plastic"]
