"""Files with meaning: real capture folders and rendered dataset samples."""
