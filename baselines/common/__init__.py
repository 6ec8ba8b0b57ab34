"""Pieces shared by every algorithm: networks, replay buffer, evaluation, training context."""
