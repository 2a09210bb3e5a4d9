"""Skeleton sources an agent can read from: one module per kind, SDKs imported lazily."""
