"""Stand-ins for the world: the MuJoCo plant, protocol emulators, the reference policy server."""
