"""Where torch work runs: the `--device` choice (select), mixed precision for the nets (precision), the
torchrun process group with the backend that fits the device (distributed), work split by index across
processes or machines (shard), and the shared command-line options (options). options and shard are torch-free."""
