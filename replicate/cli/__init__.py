"""The command line (``python -m replicate``): thin; each subcommand declares its options and
calls the layer below. The figures' own commands come from the figure registry."""
