"""Universal Robots e-Series arms over RTDE, through the real ur_rtde library.

``URRTDEDriver`` (driver.py) implements the warden driver hooks; ``URSettings`` (settings.py) is
its manifest table; ``tables.py`` holds the controller's status words and what they mean;
``gripper.py`` is the tool-output gripper's wiring; ``link.py`` is the only code that touches
ur_rtde objects; ``watchdog.py`` is the controller-side RTDE watchdog (what ur_rtde does, how
the link arms, feeds, lengthens and removes it); ``stopping.py`` runs a stop on the device
thread while the loop's ticks go on; ``setpoints.py`` checks and clips setpoints; ``probe.py``
checks a controller in plain sockets before the library (whose constructors hold the GIL) is let
near it.
"""
