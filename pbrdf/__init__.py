"""pbrdf: the bottom layer of the project.

Polarized light (Stokes/Mueller algebra, Fresnel), Mueller-matrix validity, the display-camera
measurement model and its decoder. Only numpy and scipy here (torch only for the pBRDF
generator); never bpy or mitsuba.

Import the modules directly: ``from pbrdf import camera, decode, fresnel, mueller, stokes, validity``.
"""
