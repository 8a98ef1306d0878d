"""Prefect flows: thin wiring of ltmstore calls (no numerics here)."""
