"""File mechanics without physics: atomic writes, EXR images and Mitsuba tensor files."""
