"""Fabrication: tolerances and sampled as-built chips, and where a die sat on its wafer."""
