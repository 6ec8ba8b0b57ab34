"""The paper's claims: the declaration file's reader, check kinds, judging, verdicts, the
measures' grouping of runs, published numbers and the judging of confirmatory experiments.
Imports the store and grids, never reports or figures."""
