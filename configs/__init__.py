"""Scenario files (TOML). Also importable as ``sitl.configs``, so an installed ``sitl``
finds its built-in scenarios (``sitl demo``) as package data."""
