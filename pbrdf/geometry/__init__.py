"""Surface geometry from measured maps: depth from normals."""
