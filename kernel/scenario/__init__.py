"""Scenario files and run journals (docs/contract.md §7): load, validate, turn into core inputs."""

from kernel.scenario.load import Scenario, ScenarioError, load_scenario

__all__ = ["Scenario", "ScenarioError", "load_scenario"]
