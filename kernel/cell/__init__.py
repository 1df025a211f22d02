"""The assembly cell: the core, the skills and a driver put together and run tick by tick."""
