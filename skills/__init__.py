"""Skills: the task FSM, phase contract cards, and the classical owners (contact, planner)."""
