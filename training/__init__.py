"""aat training side: lenses, ray tracing, PSFs, rendering, depth-from-focus nets (torch)."""
