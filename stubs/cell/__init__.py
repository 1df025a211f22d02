"""Stand-ins for a cell's world, found by the kernel through entry points (kernel.app.standins).

``sim_world`` (the in-process MuJoCo plant), ``emulated`` (a vendor driver's emulator process
with the plant behind it), ``reference_server`` and ``local_policy`` (the scripted reference
policy, as a process or in process), ``operator`` (the simulated operator).
"""
