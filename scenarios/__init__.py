"""Shipped data: plant files and scenario/study TOML files (package data)."""
