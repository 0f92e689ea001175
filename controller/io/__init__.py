"""File formats at the edge: images in and out."""
