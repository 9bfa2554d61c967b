"""pbrdf: the bottom layer of the project, physics and file formats only.

Sub-packages, in the order light flows through them:

* :mod:`pbrdf.polar` - polarized light: Stokes vectors, Mueller matrices, Fresnel, validity.
* :mod:`pbrdf.brdf` - materials: the Disney BRDF, polarimetric microfacet pBRDFs, measured tables.
* :mod:`pbrdf.expansion` - growing a few measured pBRDFs into many (PCA, generator, filter).
* :mod:`pbrdf.sensor` - the display-camera rig: geometry, projection, sensor model, decoding.
* :mod:`pbrdf.data` - captures and dataset samples on disk.
* :mod:`pbrdf.io` - atomic writes, EXR files and Mitsuba tensor files.

Only numpy and scipy here (torch only for the pBRDF generator); never bpy, mitsuba or anything
from the layers above. Import modules from their sub-package: ``from pbrdf.polar import stokes``.
"""
