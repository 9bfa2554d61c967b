"""Polarized light: Stokes vectors, Mueller matrices of optical elements, Fresnel, validity."""
