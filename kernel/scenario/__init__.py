"""Scenario files and run journals (docs/contract.md §7): load, validate, turn into core inputs.

The loader is :mod:`kernel.scenario.load`. This package imports nothing itself, so a reader of
its leaf modules (``fields``, ``bounds``, ``document``: the safety monitor's view of a manifest
among them) does not load the core with it.
"""
