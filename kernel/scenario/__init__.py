"""Scenario files and run journals (docs/contract.md §7): load, validate, turn into core inputs.

The loader is :mod:`kernel.scenario.load` (with the events of :mod:`kernel.scenario.events`);
the sections a scenario shares with a manifest are built into the core's configuration by
:mod:`kernel.config`. The leaf readers here (``fields``, ``bounds``, ``document``) are shared by
every file reader, the safety monitor's view of a manifest among them. This package imports
nothing itself, so a reader of a leaf does not load the core with it.
"""
