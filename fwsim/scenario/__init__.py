"""Scenario YAML -> validated configuration; the field reference and JSON Schema."""
