"""What runs write: figures (PNG), the 3D scene (glTF binary) and the summary table."""
