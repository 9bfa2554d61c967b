"""Materials: the Disney BRDF, polarimetric microfacet pBRDFs, measured pBRDF tables and their geometry, seeds."""
