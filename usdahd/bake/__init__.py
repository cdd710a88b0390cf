"""The baker: texels, ray tracing, integration and post-processing (see docs/conventions.md)."""
