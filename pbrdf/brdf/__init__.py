"""Materials: the Disney BRDF, polarimetric microfacet pBRDFs, measured pBRDF tables, seed materials."""
