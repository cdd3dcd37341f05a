"""The time-critical lumigraph (Sloan, Cohen & Gortler 1997): two-plane light fields,
their capture, and reconstruction by alpha-blended textured triangles (§2.3)."""
