"""File mechanics without physics: atomic writes and EXR images."""
