"""The figures as plug-ins: the registry, one module per figure, their commands, plots and
forest plots, and a figure's train-then-report step. Imports reports, claims, grids, store."""
