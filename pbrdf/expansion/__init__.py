"""pBRDF expansion: factorisation and PCA of tables, the conditional generator, the resumable run."""
