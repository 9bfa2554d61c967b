"""The display-camera rig: geometry and projection, the polarization sensor model, decoding to nine maps."""
