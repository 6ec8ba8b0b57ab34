"""The replication harness: run specs, demonstrations, run store, statistics, reports, CLI."""

__version__ = "0.1.0"
