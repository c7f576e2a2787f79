"""Browser-facing clients of the lab (the viser web viewer)."""
