"""Training data: procedural SVBRDFs, dataset readers and physically consistent augmentations.

Modules:
    procedural  seeded, vectorised generator of real-looking SVBRDFs (:func:`procedural.generate`)
    noise       the texture primitives it is built from (spectral noise, Voronoi cells, lookups)
    augment     flips / 90-degree rotations / crops / albedo and roughness jitter that keep normals right
    datasets    torch Datasets: the procedural stream, Deschaintre-format strips, folders of maps
    preview     contact sheets of materials (maps + a reference rendering) for looking at them
    stats       coverage statistics (roughness, albedos, slopes) of a set of materials
    encoding    which albedo encoding a dataset stores, told by its strips' render tiles
"""

from .procedural import FAMILIES, family_of, generate, generate_indices, height_to_normal, material

__all__ = ["FAMILIES", "family_of", "generate", "generate_indices", "height_to_normal", "material"]
