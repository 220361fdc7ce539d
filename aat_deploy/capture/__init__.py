"""Reading capture folders: frame files, their metadata (EXIF, maker notes, XMP, exiftool) and pixels."""
