"""Rendering focal stacks without torch: the simulator's effects registry (`effects/`)."""
