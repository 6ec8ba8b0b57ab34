"""The run store: what a run is (spec and address), reading runs back and asking for them by
grid or by cell (query), training one seed batch into the store (runner, recorder), provenance,
checkpoint places and the carry. Imports only errors, stats, demos and baselines/envs."""
