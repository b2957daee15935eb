"""flight stage."""
