"""Data sources: real Cornell / Jacquard readers, splits and synthetic Cornell-format scenes."""
